// Two server instances' directory members on the loopback profile (server/map_directory.hpp):
// the claim rule settles a map claimed twice the same way on both sides, a released claim frees
// the map, and an instance creates only the new maps its group takes.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <string>
#include <thread>

#include "fslam/server/map_directory.hpp"
#include "fslam/server/server.hpp"
#include "test_support.hpp"

namespace fslam::server {
namespace {

class MapDirectoryMembers : public ::testing::Test {
 protected:
  void SetUp() override {
    test::use_loopback_dds();
    const std::string prefix = "dir" + std::to_string(getpid());
    pa_ = client::make_participant(DDS_DOMAIN_DEFAULT);
    pb_ = client::make_participant(DDS_DOMAIN_DEFAULT);
    a_ = std::make_unique<MapDirectoryMember>(pa_, prefix, InstanceRecord{"a", prefix + "/a", "a-*"});
    b_ = std::make_unique<MapDirectoryMember>(pb_, prefix, InstanceRecord{"b", prefix + "/b", "*"});
  }
  // Polls `done` for up to 10 s (discovery on loopback takes well under a second).
  template <class F>
  static bool eventually(F done) {
    for (int i = 0; i < 1000; ++i) {
      if (done()) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return false;
  }
  client::Entity pa_, pb_;
  std::unique_ptr<MapDirectoryMember> a_, b_;
};

TEST_F(MapDirectoryMembers, TheLaterClaimGivesTheMapUpAndBothSidesAgree) {
  a_->claim("m", 100);
  b_->claim("m", 200);
  std::vector<std::pair<std::string, client::MapClaimInfo>> lost;
  ASSERT_TRUE(eventually([&] {
    lost = b_->take_lost();
    return !lost.empty();
  }));
  ASSERT_EQ(lost.size(), 1u);
  EXPECT_EQ(lost[0].first, "m");
  EXPECT_EQ(lost[0].second.instance, "a");
  EXPECT_EQ(lost[0].second.service_prefix.substr(lost[0].second.service_prefix.size() - 2), "/a");
  EXPECT_TRUE(a_->take_lost().empty());
  std::string why;
  EXPECT_TRUE(a_->may_claim("m", false, &why)) << why;
  EXPECT_FALSE(b_->may_claim("m", false, &why));
  EXPECT_NE(why.find("map 'm' is served by instance 'a'"), std::string::npos) << why;
}

TEST_F(MapDirectoryMembers, ClaimsAtTheSameInstantGoToTheSmallerInstanceName) {
  b_->claim("t", 300);
  a_->claim("t", 300);
  std::vector<std::pair<std::string, client::MapClaimInfo>> lost;
  ASSERT_TRUE(eventually([&] {
    lost = b_->take_lost();
    return !lost.empty();
  }));
  EXPECT_EQ(lost[0].second.instance, "a");
  // a saw b's claim too (b's record arrived), and keeps the map.
  ASSERT_TRUE(eventually([&] { return !b_->may_claim("t", false, nullptr); }));
  EXPECT_TRUE(a_->take_lost().empty());
}

TEST_F(MapDirectoryMembers, AReleasedClaimFreesTheMap) {
  a_->claim("r");
  std::string why;
  ASSERT_TRUE(eventually([&] { return !b_->may_claim("r", false, &why); }));
  a_->release("r");
  EXPECT_TRUE(eventually([&] { return b_->may_claim("r", false, &why); })) << why;
}

TEST_F(MapDirectoryMembers, AnInstanceCreatesOnlyTheNewMapsItsGroupTakes) {
  std::string why;
  EXPECT_TRUE(a_->may_claim("a-kitchen", true, &why)) << why;
  EXPECT_FALSE(a_->may_claim("hall", true, &why));
  EXPECT_NE(why.find("creates only maps matching 'a-*'"), std::string::npos) << why;
  EXPECT_TRUE(b_->may_claim("hall", true, &why)) << why;
}

TEST(ScaleOutConfig, AnInstanceServesOnATopicSafePrefixOfItsOwn) {
  ServerConfig config;
  EXPECT_EQ(config.service_prefix(), "fslam");  // no instance: the single-server layout
  config.instance = "fslam-0";                   // a Kubernetes pod name
  EXPECT_EQ(config.service_prefix(), "fslam/fslam_0");
  std::string why;
  EXPECT_TRUE(config.is_valid(&why)) << why;
  config.instance = "a/b";
  EXPECT_FALSE(config.is_valid(&why));
  EXPECT_NE(why.find("instance 'a/b'"), std::string::npos) << why;
}

}  // namespace
}  // namespace fslam::server
