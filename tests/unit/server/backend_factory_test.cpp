#include "fslam/server/backend_factory.hpp"

#include <gtest/gtest.h>

namespace fslam::server {
namespace {

TEST(BackendFactory, CpuAlwaysAvailable) {
  std::string notice, why;
  auto backend = make_backend("cpu", &notice, &why);
  ASSERT_TRUE(backend) << why;
  EXPECT_EQ(backend->name(), "cpu");
}

TEST(BackendFactory, AutoFallsBackWithOneLineNotice) {
  std::string notice, why;
  auto backend = make_backend("auto", &notice, &why);
  ASSERT_TRUE(backend) << why;
  if (backend->name() == "cpu") {
    EXPECT_NE(notice.find("using the CPU backend"), std::string::npos) << notice;
    EXPECT_EQ(notice.find('\n'), std::string::npos);
  }
}

TEST(BackendFactory, CudaWithoutGpuOrUnknownIsAConfigError) {
  std::string notice, why;
  EXPECT_FALSE(make_backend("gpu", &notice, &why));
  EXPECT_NE(why.find("auto, cpu or cuda"), std::string::npos);
  auto backend = make_backend("cuda", &notice, &why);
  if (!backend) {
    EXPECT_NE(why.find("cuda"), std::string::npos) << why;
  } else {
    EXPECT_EQ(backend->name().rfind("cuda", 0), 0u);
  }
}

}  // namespace
}  // namespace fslam::server
