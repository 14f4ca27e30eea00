// Eigen's matrix products split their depth into blocks sized from the processor's caches, read
// from CPUID, and sum block by block, so one product rounds differently on processors with other
// caches. Eigen's own planner (computeProductBlockingSizes) puts the feature autoencoder's
// 352-deep products in one block with a 48 KiB L1 (the Intel VM it ran on) and in two of 184 with
// a 32 KiB L1, so the same training can round differently on each. Planning with fixed cache
// sizes makes every product block, and so round, the same everywhere (docs/architecture.md,
// "Reproducible numbers").
#pragma once

namespace fslam::core {

// Has Eigen plan its products for fixed cache sizes (its own x86 defaults: 32 KiB, 256 KiB,
// 2 MiB) instead of this processor's, for the rest of the process. Call at start-up, before any
// thread runs a product (the setting is a process-wide, unsynchronised static of Eigen's).
void use_portable_product_blocking();

}  // namespace fslam::core
