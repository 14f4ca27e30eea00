// Map export for viewers (REQUEST_MAP_GAUSSIANS, docs/protocol.md "Map export"): a map version's
// Gaussians as compact 32-byte records, read in bounded chunks so that a large map never becomes
// one unbounded DDS sample.
#pragma once

#include <cstddef>
#include <cstdint>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "fslam/client/client.hpp"
#include "fslam/core/map/gaussian_map.hpp"
#include "fslam/proto/types.h"

namespace fslam::server {

// Bytes of one exported Gaussian on the wire (the client unpacks them: unpack_gaussian).
using client::kGaussianRecordBytes;
// Most Gaussians in one chunk: 32768 x 32 B = 1 MiB per Result sample.
constexpr std::uint32_t kMaxExportChunk = 32768;

// Appends Gaussians [first, first + count) of `map` as records to `out` (count * 32 bytes):
// mean (3 x float32, world, m); standard deviations along the Gaussian's axes with the 3D filter
// applied (3 x float32, m); rotation Gaussian -> world as a unit quaternion w, x, y, z scaled by
// 127 (4 x int8); colour of the degree-0 term (3 x uint8 RGB) and opacity after the 3D filter
// (uint8), all little-endian. The caller checks the range.
void encode_gaussian_records(const core::GaussianMap& map, std::size_t first, std::size_t count,
                             std::vector<std::uint8_t>* out);

// One request for a chunk, as the fields of the Request sample give it.
struct ExportRequest {
  std::uint64_t since_version = 0;  // nothing is sent when the newest version is not newer
  std::uint64_t version = 0;        // 0: begin a read at the newest version; else go on with it
  std::uint32_t first = 0;          // index of the chunk's first Gaussian
  std::uint32_t max_count = 0;      // 0 or more than kMaxExportChunk: kMaxExportChunk
};

struct ExportChunk {
  std::uint64_t version = 0;        // the version read (the newest one when unchanged)
  std::uint64_t total = 0;          // Gaussians in that version
  std::uint32_t first = 0, count = 0;
  std::vector<std::uint8_t> records;  // [count, kGaussianRecordBytes]
};

// The export side of one map: holds the versions that chunked reads are going through, so that
// every chunk of a read comes from one version even while the map grows. A read begun at version
// V can go on while V is one of the last kHeldVersions versions begun (two viewers reading at
// once each keep theirs); after that its next chunk is refused and the reader starts again.
class MapExporter {
 public:
  static constexpr std::size_t kHeldVersions = 2;
  // The chunk `request` asks for from `versions`. False with `why` for a version no longer held
  // or a first index beyond the version's size.
  bool chunk(const core::MapVersions& versions, const ExportRequest& request, ExportChunk* out,
             std::string* why);

 private:
  std::mutex mutex_;
  std::vector<std::pair<std::uint64_t, core::MapVersions::Version>> held_;  // oldest first
};

// The Request fields of REQUEST_MAP_GAUSSIANS.
ExportRequest export_request_of(const fslam_proto_Request& msg);

// Answers REQUEST_MAP_GAUSSIANS from `exporter`: fills the result's version, size and chunk
// fields; its `gaussians` sequence points into `records`, which must outlive the write.
bool answer_map_gaussians(const core::MapVersions& versions, MapExporter* exporter,
                          const ExportRequest& request, fslam_proto_Result* result,
                          std::vector<std::uint8_t>* records, std::string* why);

}  // namespace fslam::server
