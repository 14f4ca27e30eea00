#include "fslam/client/map_directory.hpp"

#include <fnmatch.h>

#include <chrono>
#include <map>
#include <set>
#include <thread>
#include <tuple>

#include "fslam/proto/types.h"

namespace fslam::client {
namespace {

bool fail(std::string* why, const std::string& message) {
  if (why) *why = message;
  return false;
}

// FNV-1a, 64 bits: a stable hash every client computes alike (std::hash may differ by build).
std::uint64_t fnv1a(const std::string& text, std::uint64_t h = 1469598103934665603ull) {
  for (const unsigned char c : text) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

// splitmix64's finaliser: FNV-1a alone leaves the high bits poorly mixed for names that differ
// only at the end, and rendezvous hashing compares whole weights (maps piled onto one instance).
std::uint64_t mix(std::uint64_t x) {
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

// "a: m1, m2; b: (none)" for error messages.
std::string describe(const std::vector<MapClaimInfo>& entries) {
  std::map<std::string, std::vector<std::string>> by_instance;
  for (const MapClaimInfo& e : entries) {
    auto& maps = by_instance[e.instance];
    if (!e.map_name.empty()) maps.push_back(e.map_name);
  }
  std::string text;
  for (const auto& [instance, maps] : by_instance) {
    if (!text.empty()) text += "; ";
    text += instance + ":";
    if (maps.empty()) text += " (none)";
    for (std::size_t i = 0; i < maps.size(); ++i) text += (i ? ", " : " ") + maps[i];
  }
  return text;
}

}  // namespace

bool claim_precedes(const MapClaimInfo& a, const MapClaimInfo& b) {
  return std::tie(a.claimed_at_ns, a.instance) < std::tie(b.claimed_at_ns, b.instance);
}

bool map_group_matches(const std::string& group, const std::string& map) {
  return !group.empty() && fnmatch(group.c_str(), map.c_str(), 0) == 0;
}

const MapClaimInfo* place_new_map(const std::vector<MapClaimInfo>& records, const std::string& map) {
  const MapClaimInfo* best = nullptr;
  std::uint64_t best_weight = 0;
  for (const MapClaimInfo& r : records) {
    if (!r.map_name.empty() || !map_group_matches(r.map_group, map)) continue;
    const std::uint64_t weight = mix(fnv1a(map, fnv1a(r.instance + '\0')));
    if (!best || weight > best_weight || (weight == best_weight && r.instance < best->instance)) {
      best = &r;
      best_weight = weight;
    }
  }
  return best;
}

MapDirectory::MapDirectory(const std::string& prefix, dds_domainid_t domain) : prefix_(prefix) {
  participant_ = make_participant(domain);
  topic_ = make_topic(participant_, &fslam_proto_MapClaim_desc, prefix, "maps");
  reader_ = make_reader(participant_, topic_, Delivery::durable);
}

std::vector<MapClaimInfo> read_live_claims(dds_entity_t reader) {
  // One read sees every entry (a read cannot page on): room for this many maps and instances.
  constexpr std::size_t kMaxEntries = 4096;
  std::vector<void*> samples(kMaxEntries, nullptr);
  std::vector<dds_sample_info_t> info(kMaxEntries);
  // read, not take: the reader keeps the newest sample per (map, instance) for the next look;
  // samples already read come back too (any sample state), and only alive instances count.
  const std::int32_t n =
      dds_read_mask(reader, samples.data(), info.data(), kMaxEntries, kMaxEntries,
                    DDS_ANY_SAMPLE_STATE | DDS_ANY_VIEW_STATE | DDS_ALIVE_INSTANCE_STATE);
  std::vector<MapClaimInfo> out;
  auto text = [](const char* s) { return std::string(s ? s : ""); };
  for (std::int32_t i = 0; i < n; ++i) {
    if (!info[static_cast<std::size_t>(i)].valid_data) continue;
    const auto& c = *static_cast<const fslam_proto_MapClaim*>(samples[static_cast<std::size_t>(i)]);
    out.push_back({text(c.map_name), text(c.instance), text(c.service_prefix), c.claimed_at_ns,
                   text(c.map_group)});
  }
  if (n > 0) dds_return_loan(reader, samples.data(), n);
  return out;
}

std::vector<MapClaimInfo> MapDirectory::entries() const { return read_live_claims(reader_.get()); }

std::vector<MapClaimInfo> MapDirectory::discover(int settle_ms, int timeout_ms) const {
  MapLocation ignored;
  std::string why;
  locate("", false, settle_ms, timeout_ms, &ignored, &why);
  return entries();
}

bool MapDirectory::locate(const std::string& map, bool allow_new, int settle_ms, int timeout_ms,
                          MapLocation* location, std::string* why) const {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  const auto deadline = start + std::chrono::milliseconds(timeout_ms);
  auto last_new_instance = start;
  std::set<std::string> instances;
  std::vector<MapClaimInfo> now;
  for (;;) {
    now = entries();
    const MapClaimInfo* holder = nullptr;
    for (const MapClaimInfo& e : now) {
      if (e.map_name.empty()) {
        if (instances.insert(e.instance).second) last_new_instance = Clock::now();
      } else if (!map.empty() && e.map_name == map && (!holder || claim_precedes(e, *holder))) {
        holder = &e;
      }
    }
    if (holder) {
      *location = {holder->instance, holder->service_prefix, true};
      return true;
    }
    const auto t = Clock::now();
    if (!instances.empty() && t - last_new_instance >= std::chrono::milliseconds(settle_ms)) break;
    if (t >= deadline) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  if (instances.empty()) {
    return fail(why, "no featureslam server found on prefix '" + prefix_ + "' within " +
                         std::to_string(timeout_ms / 1000.0).substr(0, 4) +
                         " s (is fslam-server running on this DDS domain and profile?)");
  }
  if (allow_new) {
    std::vector<MapClaimInfo> records;
    for (const MapClaimInfo& e : now)
      if (e.map_name.empty()) records.push_back(e);
    if (const MapClaimInfo* r = place_new_map(records, map)) {
      *location = {r->instance, r->service_prefix, false};
      return true;
    }
    std::string groups;
    for (const MapClaimInfo& r : records) {
      groups += (groups.empty() ? "" : ", ") + r.instance + " '" + r.map_group + "'";
    }
    return fail(why, "no instance on prefix '" + prefix_ + "' serves map '" + map +
                         "' or creates new maps of that name (map groups: " + groups + ")");
  }
  return fail(why, "no instance on prefix '" + prefix_ + "' serves map '" + map + "' (served: " +
                       describe(now) + ")");
}

}  // namespace fslam::client
