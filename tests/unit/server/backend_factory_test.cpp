#include "fslam/server/backend_factory.hpp"

#include <gtest/gtest.h>

namespace fslam::server {
namespace {

// Rendering takes the GPU when there is one; mapping takes it only when asked for.
TEST(BackendFactory, TheRasteriserFollowsItsUse) {
  std::string notice, why;
  auto render = make_rasterizer("auto", RasterUse::kRender, &notice, &why);
  ASSERT_TRUE(render) << why;
  if (render->name() == "cpu") {
    EXPECT_NE(notice.find("using the CPU rasteriser"), std::string::npos) << notice;
    EXPECT_EQ(notice.find('\n'), std::string::npos);
  } else {
    EXPECT_EQ(render->name().rfind("cuda", 0), 0u) << render->name();
  }
  notice.clear();
  auto mapping = make_rasterizer("auto", RasterUse::kMapping, &notice, &why);
  ASSERT_TRUE(mapping) << why;
  EXPECT_EQ(mapping->name(), "cpu");
  EXPECT_NE(notice.find("opt-in"), std::string::npos) << notice;
  auto cuda = make_rasterizer("cuda", RasterUse::kMapping, &notice, &why);
  if (!cuda) {
    EXPECT_NE(why.find("cuda"), std::string::npos) << why;
  } else {
    EXPECT_EQ(cuda->name().rfind("cuda", 0), 0u) << cuda->name();
  }
  EXPECT_FALSE(make_rasterizer("gpu", RasterUse::kRender, &notice, &why));
  EXPECT_NE(why.find("auto, cpu or cuda"), std::string::npos) << why;
  auto cpu = make_rasterizer("cpu", RasterUse::kRender, &notice, &why);
  ASSERT_TRUE(cpu) << why;
  EXPECT_EQ(cpu->name(), "cpu");
}

}  // namespace
}  // namespace fslam::server
