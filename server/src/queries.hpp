// The server's queries (docs/protocol.md): render, segment, map export, save and load requests,
// accepted into a bounded queue and answered on query threads against the newest map version,
// so that any number of clients can query any map while it is being built.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <utility>
#include <thread>
#include <unordered_map>
#include <vector>

#include <Eigen/Geometry>

#include "fslam/core/render/rasterizer.hpp"
#include "fslam/core/segmentation/prompts.hpp"
#include "fslam/proto/types.h"
#include "fslam/server/grounding.hpp"
#include "fslam/server/server.hpp"
#include "fslam/server/wire.hpp"
#include "fslam/server/rate_limit.hpp"

namespace fslam::server {

struct MapEntry;
class MapRegistry;
class Counters;

class Queries {
 public:
  using Log = std::function<void(const std::string&)>;
  // All references must outlive the queries; `grounding` may be null (text queries are refused).
  Queries(const ServerConfig& config, MapRegistry& maps, const Replies& replies, Counters& counters,
          const core::Rasterizer& rasterizer, const GroundingDetector* grounding, Log log);
  ~Queries();

  // Starts server.query_threads threads answering the queue.
  void start();
  // A fslam/requests sample: queued, or refused as busy when server.query_queue_capacity wait.
  // A (client, request id) still queued or being answered (a client's resend, docs/protocol.md
  // "Resending") is dropped. One answered already gets its answer again, as that may have been
  // lost: the remembered answer when it carried no images or Gaussians (saves, loads, errors: so
  // these run once), else it runs again (renders, segmentations and exports only read).
  void accept(const fslam_proto_Request& msg);
  // Answers without images or Gaussians remembered for resends.
  static constexpr std::size_t kRememberedAnswers = 1024;
  // Per-client request rates remembered before they are forgotten (and their limits restart).
  static constexpr std::size_t kRememberedClients = 4096;
  // Answers what is queued, then stops the threads.
  void stop();

 private:
  void serve();
  void answer(const Query& query);
  // Fill `result`, whose images point into `images`.
  bool render(const Query& query, MapEntry& map, fslam_proto_Result* result, ResultImages* images,
              std::string* why) const;
  bool segment(const Query& query, MapEntry& map, fslam_proto_Result* result, ResultImages* images,
               std::string* why) const;
  // The promptless instances of the newest version in `view`, as ids + 1 (CV_16UC1); `version`
  // and `version_number` become the version labelled.
  bool instance_image(MapEntry& map, const core::RenderView& view,
                      std::shared_ptr<const core::GaussianMap>* version, std::uint64_t* version_number,
                      cv::Mat* image, std::string* why) const;
  // The object that points, boxes or a text select in `view`, as a mask (CV_8UC1) in `out_view`.
  bool selection_image(const Query& query, const core::GaussianMap& version, const core::RenderView& view,
                       const std::vector<Eigen::Vector2d>& points, std::vector<core::BoxPrompt> boxes,
                       const core::RenderView& out_view, cv::Mat* image, std::string* why) const;
  // The camera and pose a RenderRequest names (pose or tracked frame, intrinsics or the map's
  // camera), checked against the server's limits.
  bool resolve_view(const fslam_proto_RenderRequest& request, MapEntry& map, core::RenderView* view,
                    Eigen::Isometry3d* T_world_camera, std::string* why) const;

  const ServerConfig& config_;
  MapRegistry& maps_;
  const Replies& replies_;
  Counters& counters_;
  const core::Rasterizer& rasterizer_;
  const GroundingDetector* grounding_;
  Log log_;
  std::vector<std::thread> threads_;
  std::mutex mutex_;  // guards everything below
  std::deque<std::unique_ptr<Query>> queue_;
  std::unordered_map<std::string, RateLimit> client_rates_;  // server.max_client_requests_per_s
  using RequestKey = std::pair<std::string, std::uint64_t>;  // (client, request id)
  struct SmallAnswer {
    std::string map_name, error, path;
    bool ok = false;
    std::uint64_t map_version = 0, map_gaussians = 0;
  };
  void remember_locked(const RequestKey& key, SmallAnswer answer);
  std::set<RequestKey> in_flight_;                // queued or being answered
  std::map<RequestKey, SmallAnswer> answered_;    // the last kRememberedAnswers small answers
  std::deque<RequestKey> answered_order_;         // oldest first
  std::condition_variable wake_;
  bool stopping_ = false;
  std::thread refiner_;    // REQUEST_REFINE_MAP, one at a time (joined by the next and by stop)
  bool refining_ = false;  // refiner_ has not answered yet
};

}  // namespace fslam::server
