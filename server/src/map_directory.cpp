#include "fslam/server/map_directory.hpp"

#include <unistd.h>

#include <chrono>

#include "fslam/proto/types.h"

namespace fslam::server {

std::uint64_t utc_now_ns() {
  return static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::system_clock::now().time_since_epoch())
                                        .count());
}

std::string default_instance_name() {
  char host[128] = "host";
  gethostname(host, sizeof host - 1);
  return std::string(host) + "-" + std::to_string(getpid());
}

MapDirectoryMember::MapDirectoryMember(const client::Entity& participant, const std::string& prefix,
                                       const InstanceRecord& self)
    : self_(self), started_ns_(utc_now_ns()) {
  using client::Delivery;
  topic_ = client::make_topic(participant, &fslam_proto_MapClaim_desc, prefix, "maps");
  writer_ = client::make_writer(participant, topic_, Delivery::durable);
  reader_ = client::make_reader(participant, topic_, Delivery::durable);
  write("", started_ns_);
}

MapDirectoryMember::~MapDirectoryMember() {
  // Deleting the writer unregisters every claim: readers see them go at once, not at lease end.
  writer_.reset();
}

void MapDirectoryMember::write(const std::string& map, std::uint64_t claimed_at_ns) {
  fslam_proto_MapClaim c{};
  std::string name = map, instance = self_.instance, prefix = self_.service_prefix,
              group = map.empty() ? self_.map_group : "";
  c.map_name = name.data();
  c.instance = instance.data();
  c.service_prefix = prefix.data();
  c.claimed_at_ns = claimed_at_ns;
  c.map_group = group.data();
  dds_write(writer_.get(), &c);
}

void MapDirectoryMember::claim(const std::string& map, std::uint64_t at_ns) {
  std::uint64_t at = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    auto [it, fresh] = claims_.emplace(map, at_ns != 0 ? at_ns : utc_now_ns());
    if (!fresh) return;
    at = it->second;
  }
  write(map, at);
}

void MapDirectoryMember::release(const std::string& map) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (claims_.erase(map) == 0) return;
  }
  fslam_proto_MapClaim key{};
  std::string name = map, instance = self_.instance, empty;
  key.map_name = name.data();
  key.instance = instance.data();
  key.service_prefix = empty.data();
  key.map_group = empty.data();
  dds_dispose(writer_.get(), &key);
}

std::vector<client::MapClaimInfo> MapDirectoryMember::others() const {
  std::vector<client::MapClaimInfo> out;
  for (client::MapClaimInfo& e : client::read_live_claims(reader_.get())) {
    if (e.instance != self_.instance) out.push_back(std::move(e));
  }
  return out;
}

std::optional<client::MapClaimInfo> MapDirectoryMember::held_elsewhere(const std::string& map) const {
  std::optional<client::MapClaimInfo> ours;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = claims_.find(map);
    if (it != claims_.end()) ours = client::MapClaimInfo{map, self_.instance, "", it->second, ""};
  }
  std::optional<client::MapClaimInfo> best;
  for (client::MapClaimInfo& e : others()) {
    if (e.map_name != map || (ours && !client::claim_precedes(e, *ours))) continue;
    if (!best || client::claim_precedes(e, *best)) best = std::move(e);
  }
  return best;
}

bool MapDirectoryMember::may_claim(const std::string& map, bool creating, std::string* why) const {
  if (creating && !client::map_group_matches(self_.map_group, map)) {
    if (why) {
      *why = "instance '" + self_.instance + "' creates only maps matching '" + self_.map_group +
             "', not '" + map + "'";
    }
    return false;
  }
  if (const auto holder = held_elsewhere(map)) {
    if (why) {
      *why = "map '" + map + "' is served by instance '" + holder->instance + "' (prefix " +
             holder->service_prefix + ")";
    }
    return false;
  }
  return true;
}

std::vector<std::pair<std::string, client::MapClaimInfo>> MapDirectoryMember::take_lost() {
  std::map<std::string, std::uint64_t> claims;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    claims = claims_;
  }
  std::vector<std::pair<std::string, client::MapClaimInfo>> lost;
  if (claims.empty()) return lost;
  for (const client::MapClaimInfo& e : others()) {
    const auto it = claims.find(e.map_name);
    if (e.map_name.empty() || it == claims.end()) continue;
    if (client::claim_precedes(e, {e.map_name, self_.instance, "", it->second, ""})) {
      lost.emplace_back(e.map_name, e);
      claims.erase(it);  // one winner named per map is enough
    }
  }
  for (const auto& [map, winner] : lost) release(map);
  return lost;
}

}  // namespace fslam::server
