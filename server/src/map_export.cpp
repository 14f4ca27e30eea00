#include "fslam/server/map_export.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "fslam/core/error.hpp"
#include "fslam/core/math/splat_math.hpp"

namespace fslam::server {
namespace {

std::uint8_t unit_to_byte(float x) {
  return static_cast<std::uint8_t>(std::lround(std::clamp(x, 0.0f, 1.0f) * 255.0f));
}

void put_float(float x, std::uint8_t* out) {
  static_assert(sizeof(float) == 4, "records hold IEEE float32");
  std::memcpy(out, &x, 4);  // little-endian hosts only (x86-64, arm64), as the rest of the wire
}

}  // namespace

void encode_gaussian_records(const core::GaussianMap& map, std::size_t first, std::size_t count,
                             std::vector<std::uint8_t>* out) {
  const std::size_t start = out->size();
  out->resize(start + count * kGaussianRecordBytes);
  const int sh_stride = map.sh_per_gaussian();
  for (std::size_t n = 0; n < count; ++n) {
    const std::size_t i = first + n;
    std::uint8_t* r = out->data() + start + n * kGaussianRecordBytes;
    for (int k = 0; k < 3; ++k) put_float(map.means[3 * i + k], r + 4 * k);
    // The 3D smoothing filter as the rasteriser applies it (splat_math.hpp, filtered_scales):
    // variance added to every axis, opacity scaled to keep the Gaussian's mass.
    const float filter = map.filter_3d.empty() ? 0.0f : map.filter_3d[i];
    float scale[3], scale_eff[3];
    const float filter_coef = core::math::filtered_scales(&map.log_scales[3 * i], filter, scale, scale_eff);
    for (int k = 0; k < 3; ++k) put_float(scale_eff[k], r + 12 + 4 * k);
    const float* q = &map.rotations[4 * i];
    const float norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (int k = 0; k < 4; ++k) {
      const float unit = norm > 0.0f ? q[k] / norm : (k == 0 ? 1.0f : 0.0f);
      r[24 + k] = static_cast<std::uint8_t>(static_cast<std::int8_t>(std::lround(unit * 127.0f)));
    }
    // Degree 0 only: a viewer shows the view-independent colour.
    for (int c = 0; c < 3; ++c) r[28 + c] = unit_to_byte(core::sh_dc_to_rgb(map.sh[sh_stride * i + c]));
    r[31] = unit_to_byte(core::math::sigmoid(map.opacity_logits[i]) * filter_coef);
  }
}

bool MapExporter::chunk(const core::MapVersions& versions, const ExportRequest& request,
                        ExportChunk* out, std::string* why) {
  core::MapVersions::Version map;
  std::uint64_t number = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (request.version == 0) {
      // Read the number first: the map taken after it is at least that new.
      number = versions.version_number();
      map = versions.latest();
      if (number <= request.since_version) {
        *out = {};
        out->version = number;
        out->total = map->size();
        return true;
      }
      const auto same = std::find_if(held_.begin(), held_.end(),
                                     [&](const auto& h) { return h.first == number; });
      if (same == held_.end()) {
        held_.emplace_back(number, map);
        if (held_.size() > kHeldVersions) held_.erase(held_.begin());
      }
    } else {
      const auto it = std::find_if(held_.begin(), held_.end(),
                                   [&](const auto& h) { return h.first == request.version; });
      if (it == held_.end()) {
        return core::fail(why, "map export: version " + std::to_string(request.version) +
                                   " is no longer held; start again from version 0");
      }
      number = it->first;
      map = it->second;
    }
  }
  if (request.first > map->size()) {
    return core::fail(why, "map export: first Gaussian " + std::to_string(request.first) +
                               " is beyond version " + std::to_string(number) + "'s " +
                               std::to_string(map->size()));
  }
  const std::uint32_t cap =
      request.max_count == 0 ? kMaxExportChunk : std::min(request.max_count, kMaxExportChunk);
  out->version = number;
  out->total = map->size();
  out->first = request.first;
  out->count = static_cast<std::uint32_t>(std::min<std::size_t>(cap, map->size() - request.first));
  out->records.clear();
  encode_gaussian_records(*map, out->first, out->count, &out->records);
  return true;
}

ExportRequest export_request_of(const fslam_proto_Request& msg) {
  return {msg.since_version, msg.gaussians_version, msg.gaussians_first, msg.gaussians_max};
}

bool answer_map_gaussians(const core::MapVersions& versions, MapExporter* exporter,
                          const ExportRequest& request, fslam_proto_Result* result,
                          std::vector<std::uint8_t>* records, std::string* why) {
  ExportChunk chunk;
  if (!exporter->chunk(versions, request, &chunk, why)) return false;
  *records = std::move(chunk.records);
  result->map_version = chunk.version;
  result->map_gaussians = chunk.total;
  result->gaussians_first = chunk.first;
  result->gaussians_count = chunk.count;
  result->gaussians = {static_cast<std::uint32_t>(records->size()),
                       static_cast<std::uint32_t>(records->size()), records->data(), false};
  return true;
}

}  // namespace fslam::server
