// This server instance's side of the map directory (<prefix>/maps, docs/protocol.md
// "Scale-out"): it publishes the instance's record and a claim for every map it serves, reads the
// other instances' claims, and says which of its maps it must give up because another instance's
// claim precedes its own (client::claim_precedes). Scale-out needs no broker: the directory is
// plain DDS discovery plus transient-local samples.
#pragma once

#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "fslam/client/dds.hpp"
#include "fslam/client/map_directory.hpp"

namespace fslam::server {

// What an instance says about itself in the directory.
struct InstanceRecord {
  std::string instance;        // unique in the deployment
  std::string service_prefix;  // where it serves frames, requests, results
  std::string map_group;       // glob of the new map names it creates; "" = none
};

// UTC nanoseconds now: the claim time the rule orders by.
std::uint64_t utc_now_ns();

// The directory name of an instance not given one (server.instance empty): "<host>-<pid>".
std::string default_instance_name();

class MapDirectoryMember {
 public:
  // Joins <prefix>/maps on `participant` and publishes the instance's record. Throws DdsError.
  MapDirectoryMember(const client::Entity& participant, const std::string& prefix,
                     const InstanceRecord& self);
  ~MapDirectoryMember();
  MapDirectoryMember(const MapDirectoryMember&) = delete;
  MapDirectoryMember& operator=(const MapDirectoryMember&) = delete;

  // Claims `map` at `at_ns` (0: now); a map claimed again keeps its first claim time.
  void claim(const std::string& map, std::uint64_t at_ns = 0);
  // Withdraws the claim (disposes it): the map is no longer served here.
  void release(const std::string& map);
  // Another live instance's claim on `map` that holds it against ours (or any live claim by
  // another instance when we do not claim it), if there is one.
  std::optional<client::MapClaimInfo> held_elsewhere(const std::string& map) const;
  // The maps we claim that another instance holds by the rule; each is released here and comes
  // with the claim that won it. Polled by the server.
  std::vector<std::pair<std::string, client::MapClaimInfo>> take_lost();
  // Whether this instance may start serving `map`: no other live instance claims it and, for a
  // new map (`creating`), the instance's map group takes the name. False with `why`.
  bool may_claim(const std::string& map, bool creating, std::string* why) const;

 private:
  void write(const std::string& map, std::uint64_t claimed_at_ns);
  std::vector<client::MapClaimInfo> others() const;  // live entries of the other instances

  InstanceRecord self_;
  std::uint64_t started_ns_;
  client::Entity topic_, writer_, reader_;
  mutable std::mutex mutex_;
  std::map<std::string, std::uint64_t> claims_;  // map -> claimed_at_ns
};

}  // namespace fslam::server
