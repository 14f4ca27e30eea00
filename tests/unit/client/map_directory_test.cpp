// The map directory's rules, shared by servers and clients (client/map_directory.hpp): which of
// two claims holds a map, which new map names an instance's group takes, and where a new map goes.
#include <gtest/gtest.h>

#include <map>
#include <string>
#include <vector>

#include "fslam/client/map_directory.hpp"

namespace fslam::client {
namespace {

MapClaimInfo claim(const std::string& map, const std::string& instance, std::uint64_t at) {
  return {map, instance, "fslam/" + instance, at, ""};
}

MapClaimInfo record(const std::string& instance, const std::string& group) {
  return {"", instance, "fslam/" + instance, 1, group};
}

TEST(MapDirectoryRules, TheEarlierClaimHoldsTheMapTiesGoToTheSmallerInstanceName) {
  EXPECT_TRUE(claim_precedes(claim("m", "b", 100), claim("m", "a", 200)));
  EXPECT_FALSE(claim_precedes(claim("m", "a", 200), claim("m", "b", 100)));
  // Same instant: the instance names decide, the same way from either side.
  EXPECT_TRUE(claim_precedes(claim("m", "a", 100), claim("m", "b", 100)));
  EXPECT_FALSE(claim_precedes(claim("m", "b", 100), claim("m", "a", 100)));
  // A strict order: a claim never precedes itself.
  EXPECT_FALSE(claim_precedes(claim("m", "a", 100), claim("m", "a", 100)));
}

TEST(MapDirectoryRules, MapGroupsAreShellGlobsAndAnEmptyGroupTakesNothing) {
  EXPECT_TRUE(map_group_matches("*", "anything"));
  EXPECT_TRUE(map_group_matches("kitchen-*", "kitchen-2"));
  EXPECT_FALSE(map_group_matches("kitchen-*", "hall-1"));
  EXPECT_TRUE(map_group_matches("room-[0-4]", "room-3"));
  EXPECT_FALSE(map_group_matches("room-[0-4]", "room-7"));
  EXPECT_FALSE(map_group_matches("", "anything"));
}

TEST(MapDirectoryRules, ANewMapGoesToTheOnlyMatchingGroupOrNowhere) {
  const std::vector<MapClaimInfo> records = {record("a", "a-*"), record("b", "b-*"), record("c", "")};
  ASSERT_NE(place_new_map(records, "a-room"), nullptr);
  EXPECT_EQ(place_new_map(records, "a-room")->instance, "a");
  EXPECT_EQ(place_new_map(records, "b-room")->instance, "b");
  EXPECT_EQ(place_new_map(records, "c-room"), nullptr);
  // Claims are not instance records: they never place a map.
  EXPECT_EQ(place_new_map({claim("x-room", "x", 1)}, "x-room"), nullptr);
}

TEST(MapDirectoryRules, NewMapsSpreadOverInstancesWhoseGroupsOverlapAndStayPut) {
  const std::vector<MapClaimInfo> records = {record("a", "*"), record("b", "*"), record("c", "*")};
  std::map<std::string, int> per_instance;
  for (int i = 0; i < 300; ++i) {
    const std::string map = "map-" + std::to_string(i);
    const MapClaimInfo* placed = place_new_map(records, map);
    ASSERT_NE(placed, nullptr);
    ++per_instance[placed->instance];
    // The order the records arrive in does not change the choice.
    const std::vector<MapClaimInfo> reversed(records.rbegin(), records.rend());
    EXPECT_EQ(place_new_map(reversed, map)->instance, placed->instance) << map;
  }
  ASSERT_EQ(per_instance.size(), 3u);
  for (const auto& [instance, n] : per_instance) {
    EXPECT_GT(n, 60) << instance << " got " << n << " of 300 maps";  // 100 expected
  }
  // Losing an instance moves only its own maps (rendezvous hashing).
  const std::vector<MapClaimInfo> two = {record("a", "*"), record("b", "*")};
  for (int i = 0; i < 300; ++i) {
    const std::string map = "map-" + std::to_string(i);
    const std::string before = place_new_map(records, map)->instance;
    if (before != "c") {
      EXPECT_EQ(place_new_map(two, map)->instance, before) << map;
    }
  }
}

}  // namespace
}  // namespace fslam::client
