// Eigen's matrix products split their depth into blocks sized from the processor's caches, read
// from CPUID, and sum block by block, so one product rounds differently on processors with other
// caches. Measured: the feature autoencoder's 352-deep products ran in one block on a 48 KiB-L1
// Intel and in two of 184 on a 32 KiB-L1 processor, and the same training gave other weights on
// each. Planning with fixed cache sizes makes every product block, and so round, the same
// everywhere (docs/architecture.md, "Reproducible numbers").
#pragma once

namespace fslam::core {

// Has Eigen plan its products for fixed cache sizes (its own x86 defaults: 32 KiB, 256 KiB,
// 2 MiB) instead of this processor's, for the rest of the process. Call at start-up, before any
// thread runs a product (the setting is a process-wide, unsynchronised static of Eigen's).
void use_portable_product_blocking();

}  // namespace fslam::core
