// The deployment's map directory (<prefix>/maps, docs/protocol.md "Scale-out"): which server
// instance serves which map, found by DDS discovery with no broker. Servers publish their claims
// (server/src/map_directory.cpp); clients read them here to find the instance serving a map, or
// the instance that creates a new one. The rule that settles two claims on one map lives here
// once, for both sides.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "fslam/client/dds.hpp"

namespace fslam::client {

// One live entry of the directory: an instance's own record (map_name empty) or its claim on a map.
struct MapClaimInfo {
  std::string map_name;        // "" for the instance's record
  std::string instance;
  std::string service_prefix;  // where the instance's frames, requests and results topics are
  std::uint64_t claimed_at_ns = 0;  // UTC ns of the first claim
  std::string map_group;       // record only: glob of the new map names it creates ("" = none)
};

// The deterministic rule: of two claims on one map, `a` holds it when it was claimed first, ties
// broken by the smaller instance name. Every instance and client evaluates it on the same
// samples, so they all agree whatever order the claims arrived in.
bool claim_precedes(const MapClaimInfo& a, const MapClaimInfo& b);

// Whether a new map called `map` belongs to an instance's map group (a shell glob: `*`, `?`,
// `[...]`; an empty group matches nothing).
bool map_group_matches(const std::string& group, const std::string& map);

// The instance that creates a new map `map`: among `records` whose group matches, the one with
// the highest rendezvous weight (hash of instance and map), so that every client places a map on
// the same instance and maps spread over instances. Null when no group matches.
const MapClaimInfo* place_new_map(const std::vector<MapClaimInfo>& records, const std::string& map);

// Every live entry a directory reader (of fslam_proto_MapClaim, durable delivery) holds now:
// disposed claims and instances that went away are left out.
std::vector<MapClaimInfo> read_live_claims(dds_entity_t reader);

// Where a client should send its requests for one map.
struct MapLocation {
  std::string instance, service_prefix;
  bool exists = false;  // false: a new map, to be created by that instance
};

// A reader of the directory with a participant of its own. Throws DdsError.
class MapDirectory {
 public:
  MapDirectory(const std::string& prefix, dds_domainid_t domain);
  // Every live entry now (instance records and claims).
  std::vector<MapClaimInfo> entries() const;
  // Waits for discovery, then finds the instance serving `map`, or (allow_new) the one that
  // creates it. Discovery is over when the map's claim arrives, or `settle_ms` after the last new
  // instance record with at least one record seen, or at `timeout_ms`. False with `why` when no
  // instance serves the map (or none would create it), or no server answered at all.
  bool locate(const std::string& map, bool allow_new, int settle_ms, int timeout_ms,
              MapLocation* location, std::string* why) const;
  // Waits like locate() for the instances to be discovered and returns every live entry.
  std::vector<MapClaimInfo> discover(int settle_ms, int timeout_ms) const;

 private:
  std::string prefix_;
  Entity participant_, topic_, reader_;
};

}  // namespace fslam::client
