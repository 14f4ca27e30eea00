#include "fslam/core/compute/product_blocking.hpp"

#include <Eigen/Core>

namespace fslam::core {

void use_portable_product_blocking() { Eigen::setCpuCacheSizes(32 * 1024, 256 * 1024, 2 * 1024 * 1024); }

}  // namespace fslam::core
