#include "queries.hpp"

#include <cmath>
#include <cstdio>
#include <utility>

#include <opencv2/core/mat.hpp>

#include "fslam/core/error.hpp"
#include "fslam/core/segmentation/segmentation.hpp"
#include "fslam/server/map_export.hpp"
#include "fslam/server/map_files.hpp"
#include "fslam/server/render_images.hpp"
#include "fslam/server/request_checks.hpp"
#include "counters.hpp"
#include "map_registry.hpp"

namespace fslam::server {

Queries::Queries(const ServerConfig& config, MapRegistry& maps, const Replies& replies,
                 Counters& counters, const core::Rasterizer& rasterizer,
                 const GroundingDetector* grounding, Log log)
    : config_(config),
      maps_(maps),
      replies_(replies),
      counters_(counters),
      rasterizer_(rasterizer),
      grounding_(grounding),
      log_(std::move(log)) {}

Queries::~Queries() { stop(); }

void Queries::start() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = false;
  }
  for (int i = 0; i < config_.query_threads; ++i) threads_.emplace_back([this] { serve(); });
}

void Queries::stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;  // the queued requests are still answered
  }
  wake_.notify_all();
  for (std::thread& t : threads_) t.join();
  threads_.clear();
  if (refiner_.joinable()) refiner_.join();  // MapRegistry::stop_refining() ends it within a step
}

void Queries::accept(const fslam_proto_Request& msg) {
  auto query = std::make_unique<Query>(query_of(msg));
  std::thread finished_refiner;
  bool busy = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    auto key = std::make_pair(query->client, query->request_id);
    if (in_flight_.count(key) > 0) return;  // a resend of one still queued or being answered
    const auto was = answered_.find(key);
    if (was != answered_.end()) {  // a resend of one answered: its answer again, not a second run
      const SmallAnswer& a = was->second;
      fslam_proto_Result r{};
      std::string map_name = a.map_name, error = a.error, path = a.path;
      r.client = query->client.data();
      r.request_id = query->request_id;
      r.map_name = map_name.data();
      r.status = a.ok ? fslam_proto_RESULT_OK : fslam_proto_RESULT_ERROR;
      r.error = error.data();
      r.path = path.data();
      r.map_version = a.map_version;
      r.map_gaussians = a.map_gaussians;
      replies_.result(r);
      return;
    }
    if (client_rates_.size() > kRememberedClients) client_rates_.clear();  // bounded: limits restart
    auto rate = client_rates_.try_emplace(query->client, config_.max_client_requests_per_s).first;
    if (!rate->second.take()) {
      counters_.add(&ServerStats::requests_failed);
      replies_.result(msg.client, msg.request_id, query->map_name,
                      "more than " + number_text(config_.max_client_requests_per_s) +
                          " requests per second from this client (server.max_client_requests_per_s); slow down");
      return;
    }
    if (query->kind == fslam_proto_REQUEST_REFINE_MAP) {
      // Refinement takes seconds to minutes: on a thread of its own, one at a time, so that
      // renders and segmentations keep their query threads.
      if (refining_) {
        replies_.result(msg.client, msg.request_id, query->map_name,
                        "server busy: a refinement is running (one at a time); try again when it is done");
        return;
      }
      refining_ = true;
      in_flight_.insert(std::move(key));
      finished_refiner = std::move(refiner_);
      refiner_ = std::thread([this, q = std::shared_ptr<Query>(std::move(query))] {
        answer(*q);
        std::lock_guard<std::mutex> done(mutex_);
        refining_ = false;
      });
    } else if (queue_.size() < config_.query_queue_capacity) {
      in_flight_.insert(std::move(key));
      queue_.push_back(std::move(query));
      wake_.notify_one();
      return;
    } else {
      busy = true;
    }
  }
  // A refiner that finished is joined here, outside the lock its last step takes.
  if (finished_refiner.joinable()) finished_refiner.join();
  if (!busy) return;
  counters_.add(&ServerStats::requests_failed);
  replies_.result(msg.client, msg.request_id, query->map_name,
                  "server busy: " + std::to_string(config_.query_queue_capacity) +
                      " requests already waiting; try again");
}

void Queries::serve() {
  for (;;) {
    std::unique_ptr<Query> query;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [&] { return !queue_.empty() || stopping_; });
      if (queue_.empty()) return;
      query = std::move(queue_.front());
      queue_.pop_front();
    }
    answer(*query);
  }
}

void Queries::remember_locked(const RequestKey& key, SmallAnswer answer) {
  if (!answered_.emplace(key, std::move(answer)).second) return;
  answered_order_.push_back(key);
  if (answered_order_.size() > kRememberedAnswers) {
    answered_.erase(answered_order_.front());
    answered_order_.pop_front();
  }
}

void Queries::answer(const Query& query) {
  fslam_proto_Result r{};
  ResultImages images;                // image bytes the result points into
  std::vector<std::uint8_t> records;  // exported Gaussians the result points into
  std::string folder, why;
  bool ok = false;
  const std::shared_ptr<MapEntry> map = maps_.find(query.map_name);
  switch (query.kind) {
    case fslam_proto_REQUEST_RENDER:
      if (!map) why = "no map named '" + query.map_name + "'";
      else ok = render(query, *map, &r, &images, &why);
      break;
    case fslam_proto_REQUEST_SEGMENT:
      if (!map) why = "no map named '" + query.map_name + "'";
      else ok = segment(query, *map, &r, &images, &why);
      break;
    case fslam_proto_REQUEST_MAP_GAUSSIANS:
      if (!map) why = "no map named '" + query.map_name + "'";
      else ok = answer_map_gaussians(map->versions(), &map->exporter, query.export_request, &r, &records, &why);
      break;
    case fslam_proto_REQUEST_SAVE_MAP:
      if (!map) why = "no map named '" + query.map_name + "'";
      else ok = resolve_map_folder(config_.map_dir, query.path, query.map_name, &folder, &why) &&
                maps_.save(*map, folder, &why);
      break;
    case fslam_proto_REQUEST_REFINE_MAP:
      if (!map) why = "no map named '" + query.map_name + "'";
      else ok = maps_.refine(*map, query.refine_steps, &why);
      break;
    case fslam_proto_REQUEST_LOAD_MAP:
      ok = resolve_map_folder(config_.map_dir, query.path, query.map_name, &folder, &why) &&
           maps_.load(query.map_name, folder, &why);
      if (ok && log_) log_("loaded map '" + query.map_name + "' from " + folder + " on request");
      break;
    default:
      why = "unknown request kind " + std::to_string(static_cast<int>(query.kind));
  }
  if (ok && (query.kind == fslam_proto_REQUEST_SAVE_MAP || query.kind == fslam_proto_REQUEST_LOAD_MAP ||
             query.kind == fslam_proto_REQUEST_REFINE_MAP)) {
    const std::shared_ptr<MapEntry> now = maps_.find(query.map_name);
    r.map_version = now->versions().version_number();
    r.map_gaussians = now->versions().latest()->size();
  }
  std::string client = query.client, map_name = query.map_name, error = ok ? "" : why;
  r.client = client.data();
  r.request_id = query.request_id;
  r.map_name = map_name.data();
  r.status = ok ? fslam_proto_RESULT_OK : fslam_proto_RESULT_ERROR;
  r.error = error.data();
  r.path = folder.data();
  replies_.result(r);
  counters_.add(ok ? &ServerStats::requests_answered : &ServerStats::requests_failed);
  std::lock_guard<std::mutex> lock(mutex_);
  const RequestKey key{query.client, query.request_id};
  in_flight_.erase(key);
  if (r.images._length == 0 && r.gaussians._length == 0) {
    remember_locked(key, {map_name, error, folder, ok, r.map_version, r.map_gaussians});
  }
}

bool Queries::resolve_view(const fslam_proto_RenderRequest& req, MapEntry& map, core::RenderView* view,
                          Eigen::Isometry3d* T_world_camera, std::string* why) const {
  {
    std::lock_guard<std::mutex> lock(map.mutex);
    if (req.from_frame) {
      const auto it = map.pose_index.find(req.frame_id);
      if (it == map.pose_index.end()) {
        return core::fail(why, "map '" + map.name + "' has no tracked pose for frame " +
                                   std::to_string(req.frame_id));
      }
      *T_world_camera = map.poses[it->second].T_world_camera;
    } else if (!from_wire(req.T_world_camera, T_world_camera, why)) {
      return false;
    }
    view->camera = map.camera;
  }
  if (!render_camera(req.intrinsics, view->camera, map.name, config_.max_render_pixels, &view->camera, why)) {
    return false;
  }
  view->T_camera_world = T_world_camera->inverse();
  return true;
}

bool Queries::render(const Query& query, MapEntry& map, fslam_proto_Result* result, ResultImages* images,
                     std::string* why) const {
  const fslam_proto_RenderRequest& req = query.render;
  float depth_scale = 0.0f;
  if (!check_render_channels(req.channels, req.depth_scale, &depth_scale, why)) return false;
  core::RenderView view;
  Eigen::Isometry3d T_world_camera;
  std::string reason;
  if (!resolve_view(req, map, &view, &T_world_camera, &reason)) return core::fail(why, "render: " + reason);
  const std::uint64_t version_number = map.versions().version_number();
  const core::MapVersions::Version version = map.versions().latest();
  if (!render_to_wire(rasterizer_, *version, view, req.channels, depth_scale, &result->images, images, why))
    return false;
  describe_view(view, T_world_camera, &result->T_world_camera, &result->intrinsics);
  result->map_version = version_number;
  result->map_gaussians = version->size();
  return true;
}

bool Queries::segment(const Query& query, MapEntry& map, fslam_proto_Result* result, ResultImages* images,
                      std::string* why) const {
  const fslam_proto_SegmentMode mode = query.segment_mode;
  if (!check_segment_mode(mode, query.text, why)) return false;
  if (mode == fslam_proto_SEGMENT_TEXT) {
    if (!grounding_) {
      return core::fail(why, "text queries need a grounding detector: set server.grounding_model to "
                             "an ONNX model (docs/segmentation.md)");
    }
  }
  core::RenderView view, out_view;
  Eigen::Isometry3d T_world_camera, T_world_out;
  std::string reason;
  if (!resolve_view(query.render, map, &view, &T_world_camera, &reason)) {
    return core::fail(why, "segment: " + reason);
  }
  if (query.has_output_view) {
    if (!resolve_view(query.output_view, map, &out_view, &T_world_out, &reason)) {
      return core::fail(why, "segment: output view: " + reason);
    }
  } else {
    out_view = view;
    T_world_out = T_world_camera;
  }
  std::vector<Eigen::Vector2d> points;
  std::vector<core::BoxPrompt> boxes;
  if (!check_prompts(mode, query.points, query.boxes, view.camera, config_.max_prompts, &points, &boxes, why)) return false;

  std::uint64_t version_number = map.versions().version_number();
  core::MapVersions::Version version = map.versions().latest();
  cv::Mat labels_image;  // CV_16UC1 ids + 1, or CV_8UC1 mask
  if (mode == fslam_proto_SEGMENT_PROMPTLESS) {
    if (!instance_image(map, out_view, &version, &version_number, &labels_image, why)) return false;
  } else {
    if (!core::has_features(*version)) {
      return core::fail(why, "segment: the map carries no features; stream with features on");
    }
    if (!selection_image(query, *version, view, points, std::move(boxes), out_view, &labels_image, why)) {
      return false;
    }
  }
  core::RenderSettings settings;
  settings.features = false;
  core::RenderResult rendered;
  if (!rasterizer_.forward(*version, out_view, settings, &rendered, why)) return false;
  if (!attach_images({labels_image, colour_to_rgb8(rendered.colour)}, &result->images, images)) {
    return core::fail(why, "segment: cannot encode a result image");
  }
  describe_view(out_view, T_world_out, &result->T_world_camera, &result->intrinsics);
  result->map_version = version_number;
  result->map_gaussians = version->size();
  return true;
}

bool Queries::instance_image(MapEntry& map, const core::RenderView& view,
                             std::shared_ptr<const core::GaussianMap>* version, std::uint64_t* version_number,
                             cv::Mat* image, std::string* why) const {
  std::shared_ptr<const core::GaussianLabels> labels;
  {
    // Labels are computed once per map version, always for the newest, and carried from the
    // clustering before so that an object keeps its id while the map grows.
    std::lock_guard<std::mutex> lock(map.instances_mutex);
    *version_number = map.versions().version_number();
    *version = map.versions().latest();
    if (!map.instances.holds(*version) && !core::has_features(**version)) {
      return core::fail(why, "segment: the map carries no features; stream with features on");
    }
    core::VersionLabels labelled;
    if (!map.instances.labels_for(*version_number, *version, &labelled, why)) return false;
    *version_number = labelled.version_number;
    labels = labelled.labels;
  }
  cv::Mat ids;  // CV_32SC1, -1 = none
  if (!core::render_labels(rasterizer_, **version, *labels, view, core::kMinObjectAlpha, &ids, why)) return false;
  // On the wire: id + 1 in 16 bits, 0 = none; ids beyond 16 bits saturate (never seen in practice).
  ids.convertTo(*image, CV_16UC1, 1.0, 1.0);
  return true;
}

bool Queries::selection_image(const Query& query, const core::GaussianMap& version, const core::RenderView& view,
                              const std::vector<Eigen::Vector2d>& points, std::vector<core::BoxPrompt> boxes,
                              const core::RenderView& out_view, cv::Mat* image, std::string* why) const {
  const core::PromptSelector prompts(version, core::PromptConfig{});  // one graph for all boxes
  std::vector<std::uint8_t> selected;
  if (query.segment_mode == fslam_proto_SEGMENT_POINTS) {
    if (!prompts.select_by_points(rasterizer_, view, points, &selected, why)) return false;
  } else {
    if (query.segment_mode == fslam_proto_SEGMENT_TEXT) {
      // The detector looks at the prompt view as the map renders it; its boxes become prompts.
      core::RenderSettings settings;
      settings.features = false;
      core::RenderResult rendered;
      if (!rasterizer_.forward(version, view, settings, &rendered, why)) return false;
      std::vector<GroundedBox> found;
      std::string reason;
      if (!grounding_->detect(colour_to_rgb8(rendered.colour), query.text, &found, &reason)) {
        return core::fail(why, "segment: " + reason);
      }
      if (found.empty()) {
        return core::fail(why, "segment: the grounding detector found nothing for '" + query.text +
                                   "' (no box scored " + number_text(config_.grounding_box_threshold) +
                                   " or more)");
      }
      for (const GroundedBox& g : found) boxes.push_back({g.u0, g.v0, g.u1, g.v1});
    }
    // Several boxes: the union of their objects.
    if (!prompts.select_by_boxes(rasterizer_, view, boxes, &selected, why)) return false;
  }
  return core::render_selection(rasterizer_, version, selected, out_view, core::kMinObjectAlpha, image, why);
}

}  // namespace fslam::server
