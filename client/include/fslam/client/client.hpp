// The thin client: pushes RGB-D frames to a featureslam server and receives the poses it
// publishes. Depends on the wire contract (proto) and image codecs only: no Eigen, no core.
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <condition_variable>
#include <functional>
#include <map>
#include <memory>
#include <utility>
#include <vector>
#include <mutex>
#include <set>
#include <string>
#include <thread>

#include "fslam/client/dds.hpp"

namespace fslam::client {

enum class PayloadEncoding { raw, png, jpeg };

struct CameraIntrinsics {
  float fx = 0, fy = 0, cx = 0, cy = 0;  // pixels
  std::uint32_t width = 0, height = 0;
};

// One RGB-D frame as the client holds it before encoding. The pointers must stay valid for the
// duration of push_frame.
struct FrameInput {
  std::uint64_t frame_id = 0;
  double timestamp = 0.0;               // seconds
  CameraIntrinsics intrinsics;
  float depth_scale = 1000.0f;          // raw depth units per metre
  const std::uint8_t* rgb = nullptr;    // [H, W, 3] RGB
  const std::uint16_t* depth = nullptr; // [H, W] raw units, 0 = missing
  PayloadEncoding colour_encoding = PayloadEncoding::jpeg;
  PayloadEncoding depth_encoding = PayloadEncoding::png;  // raw or png: depth stays lossless
  int jpeg_quality = 90;
  bool has_gt_pose = false;             // evaluation only; the server never tracks with it
  double gt_translation[3] = {0, 0, 0}; // camera-to-world, metres
  double gt_rotation[4] = {0, 0, 0, 1}; // qx qy qz qw
};

// A frame encoded for the wire (Client::encode_frame), what Client::push_encoded publishes: for
// a client that encodes ahead of sending (a replay that must not spend its sending slots on
// encoding) or whose camera delivers compressed images. Colour: JPEG, PNG or raw RGB rows;
// depth: PNG or raw 16-bit rows (lossless), in the encodings named.
struct EncodedFrame {
  std::uint64_t frame_id = 0;
  double timestamp = 0.0;               // seconds
  CameraIntrinsics intrinsics;
  float depth_scale = 1000.0f;          // raw depth units per metre
  PayloadEncoding colour_encoding = PayloadEncoding::jpeg;
  PayloadEncoding depth_encoding = PayloadEncoding::png;
  std::vector<std::uint8_t> colour, depth;  // the encoded images
  bool has_gt_pose = false;             // evaluation only
  double gt_translation[3] = {0, 0, 0}; // camera-to-world, metres
  double gt_rotation[4] = {0, 0, 0, 1}; // qx qy qz qw
};

// A pose the server published for one frame.
struct PoseUpdate {
  std::string session;
  std::uint64_t frame_id = 0;
  double timestamp = 0.0;
  double translation[3] = {0, 0, 0};  // camera-to-world, metres
  double rotation[4] = {0, 0, 0, 1};  // qx qy qz qw
  int state = 0;                      // fslam_proto_TrackingState
  bool skipped = false;               // TRACKING_SKIPPED: accepted, never tracked; not a pose
  bool keyframe = false;
  float decode_ms = 0, queue_ms = 0, track_ms = 0;  // the server's time on this frame
  std::string note;                   // why it was skipped, lost or recovered
};

// What a session does with frames that arrive while the server's tracker is busy
// (docs/protocol.md): the server's setting, live (track the newest, skip and report older ones)
// or queue (track every frame from a bounded queue; overflow drops with an error).
enum class FramePolicy { server_default, live, queue };

// What a session does with its map (docs/protocol.md "Session modes"): build a new one, localise
// in a served one without changing it (the server relocalises the first frame and any lost one
// against the map's keyframes), or extend a served one (relocalise, then keep mapping into it).
enum class SessionMode { map, localise, extend };

// Channels of a render (the proto's CHANNEL_* bits).
enum RenderChannel : std::uint32_t { kColour = 1, kDepth = 2, kNormals = 4, kOpacity = 8 };

struct SessionOptions {
  FramePolicy policy = FramePolicy::server_default;
  SessionMode mode = SessionMode::map;
  // localise: the server pushes the map rendered at each localised pose (on_view), at most this
  // many per second (0: none), of these channels, with the frame's camera.
  double view_rate_hz = 0.0;
  std::uint32_t view_channels = kColour | kDepth;
};

// A server's answer to a request or session control, or its report of a rejected or dropped
// frame (request_id = frame id, client = session).
struct ResultUpdate {
  std::string client;
  std::uint64_t request_id = 0;
  std::string map_name;
  bool ok = false;
  std::string error;
};

// A session's health as the server reports it at a fixed rate (best effort).
struct StatusUpdate {
  std::string session, map_name, last_drop_reason;
  std::uint32_t queue_depth = 0;
  std::uint64_t frames_received = 0, frames_processed = 0, frames_dropped = 0, frames_skipped = 0;
  std::string last_skip_reason, frame_policy;  // frame_policy: "live" or "queue"
  std::string mode;                            // "map", "localise" or "extend"; "" for a map report
  float queue_ms_p50 = 0, queue_ms_p99 = 0;    // per frame: accepted -> tracking starts
  std::uint64_t map_gaussians = 0, resident_bytes = 0;
  std::uint32_t mapping_queue = 0;       // keyframes waiting for the mapper
  std::uint64_t keyframes_left_out = 0;  // real time: keyframes the mapper never got
  float decode_ms_p50 = 0, decode_ms_p99 = 0;  // per frame
  float track_ms_p50 = 0, track_ms_p99 = 0;    // per frame, wall
  float track_cpu_ms_p50 = 0, track_cpu_ms_p99 = 0;  // per frame, the server threads' CPU time
  float map_ms_p50 = 0, map_ms_p99 = 0;        // per keyframe
  bool streaming = false;               // false: a map no session streams into (session empty)
  std::uint64_t map_version = 0, frames_tracked = 0;
  bool text_queries = false;            // the server answers text prompts (grounding model)
  bool loop_closure = false;            // the session closes loops (loop_closure.enabled)
  std::uint32_t loops_closed = 0;       // loops found, verified and solved into its map
};

// Where a query looks at a map from: a pose, or the tracked pose of a frame; and a camera.
struct CameraView {
  double translation[3] = {0, 0, 0};  // camera-to-world, metres
  double rotation[4] = {0, 0, 0, 1};  // qx qy qz qw
  bool from_frame = false;            // use the tracked pose of frame_id instead
  std::uint64_t frame_id = 0;
  CameraIntrinsics intrinsics;        // width 0: the camera the map was built with
};

struct RenderQuery : CameraView {
  std::string map_name;
  std::uint32_t channels = kColour | kDepth | kNormals | kOpacity;
  float depth_scale = 1000.0f;        // depth image units per metre
};

// A decoded result image: tightly packed rows; RGB for colour and normals, 16-bit depth in
// depth_scale units (0 = nothing rendered), 8-bit opacity.
struct RenderedImage {
  std::uint32_t channel = 0;  // one RenderChannel
  std::uint32_t width = 0, height = 0;
  std::uint8_t channels = 0, bytes_per_channel = 0;
  std::vector<std::uint8_t> pixels;
};

struct RenderOutput {
  std::vector<RenderedImage> images;  // in channel bit order
  double translation[3] = {0, 0, 0}, rotation[4] = {0, 0, 0, 1};  // the pose rendered from
  CameraIntrinsics intrinsics;                                     // and the camera
  std::uint64_t map_version = 0, map_gaussians = 0;
};

// A render the server pushed at a localise session's localised pose (SessionOptions views).
struct ViewUpdate {
  std::string session, map_name;
  std::uint64_t frame_id = 0;  // the frame localised at this pose
  double timestamp = 0.0;      // that frame's
  RenderOutput render;         // the session's view channels, the pose and the frame's camera
  std::string error;           // non-empty: an image could not be decoded (render then partial)
};

// Segmentation queries (docs/segmentation.md).
enum class SegmentMode { promptless, points, boxes, text };

struct SegmentQuery {
  std::string map_name;
  SegmentMode mode = SegmentMode::promptless;
  std::vector<float> points;  // points: u, v pairs in pixels of `view`
  std::vector<float> boxes;   // boxes: u0, v0, u1, v1 quadruples in pixels of `view`
  std::string text;           // text: what to find (the server needs a grounding model)
  CameraView view;            // the view prompts are given in, and the result's unless...
  bool has_output_view = false;
  CameraView output_view;     // ...this one is given: render the labels from here instead
};

struct SegmentOutput {
  // promptless: 16-bit instance ids + 1 (0 = none); prompts: 8-bit mask, 255 = the object.
  RenderedImage labels;
  RenderedImage colour;  // RGB render of the same view
  double translation[3] = {0, 0, 0}, rotation[4] = {0, 0, 0, 1};  // the pose rendered from
  CameraIntrinsics intrinsics;                                     // and the camera
  std::uint64_t map_version = 0, map_gaussians = 0;
};

// Map export (REQUEST_MAP_GAUSSIANS, docs/protocol.md "Map export"): a map version's Gaussians
// for viewers, read in chunks of at most 32768 Gaussians (1 MiB) per DDS sample.
constexpr std::size_t kGaussianRecordBytes = 32;

struct MapGaussiansQuery {
  std::string map_name;
  std::uint64_t since_version = 0;    // nothing is read when the newest version is not newer
  std::uint32_t chunk_gaussians = 0;  // Gaussians per request (0 = the server's cap)
};

struct MapGaussians {
  std::uint64_t version = 0;   // the version read (the newest one when unchanged)
  std::uint64_t count = 0;     // Gaussians in that version
  bool unchanged = false;      // no version newer than since_version: records is empty
  std::vector<std::uint8_t> records;  // [count, kGaussianRecordBytes], docs/protocol.md
  std::uint32_t requests = 0;  // chunks asked for, restarts included
};

// One exported Gaussian, unpacked from its record.
struct GaussianRecord {
  float mean[3];      // world frame, metres
  float scale[3];     // standard deviations along the Gaussian's axes (3D filter applied), metres
  float rotation[4];  // Gaussian -> world, w x y z, unit length to within 1/127
  std::uint8_t rgb[3];
  std::uint8_t opacity;  // 3D filter applied, x 255
};
GaussianRecord unpack_gaussian(const std::uint8_t* record);

// Frames written and not yet acknowledged by the server's reader: past it push_frame waits up to
// 1 s for the server to catch up, then fails (docs/protocol.md "Flow control").
constexpr std::int32_t kFramesInFlight = 16;

struct ClientOptions {
  std::string prefix = "fslam";        // topic prefix of the deployment
  dds_domainid_t domain = DDS_DOMAIN_DEFAULT;
};

class Client {
 public:
  // Joins the domain (the network profile comes from CYCLONEDDS_URI); throws DdsError.
  explicit Client(const ClientOptions& options = {});
  ~Client();
  Client(const Client&) = delete;
  Client& operator=(const Client&) = delete;

  // Encodes the frame and publishes it on <prefix>/frames for `session`. False with `why` for
  // bad input (no session, zero or non-finite intrinsics, missing images, a lossy depth
  // encoding, an encoder failure), when DDS Security does not let this client write frames, or
  // when the server has not acknowledged the frames in flight (flow control, docs/protocol.md)
  // within `wait_ms`: the frame is then not sent.
  bool push_frame(const std::string& session, const FrameInput& frame, std::string* why, int wait_ms = 1000);
  // push_frame in two steps: encode_frame checks and encodes the frame (no DDS involved, any
  // thread), push_encoded publishes it (the same checks of the header and the flow control).
  static bool encode_frame(const FrameInput& frame, EncodedFrame* out, std::string* why);
  bool push_encoded(const std::string& session, const EncodedFrame& frame, std::string* why, int wait_ms = 1000);
  // Opens a streaming session on `map_name` (a new map, or options.mode localise or extend in a
  // served one) or closes it, and waits up to timeout_ms for the server's answer. False with `why` on
  // an error result or no answer.
  bool open_session(const std::string& session, const std::string& map_name, int timeout_ms,
                    std::string* why, const SessionOptions& options = {});
  // Closing waits for the server to track what it accepted and finish mapping; refine_steps > 0
  // then refines the map that many steps before the answer (docs/protocol.md "Refinement").
  bool close_session(const std::string& session, int timeout_ms, std::string* why,
                     std::uint32_t refine_steps = 0);
  // Query-only use: succeeds when a map of that name is served.
  bool attach_map(const std::string& map_name, int timeout_ms, std::string* why);
  // Renders a map from a pose and waits up to timeout_ms for the images.
  bool render(const RenderQuery& query, RenderOutput* output, int timeout_ms, std::string* why);
  // Segments a map (promptless, or by point, box or text prompts) and waits up to timeout_ms for
  // the labels and the colour render.
  bool segment(const SegmentQuery& query, SegmentOutput* output, int timeout_ms, std::string* why);
  // Reads a whole map version's Gaussians, chunk by chunk, all from one version; starts again
  // (up to three times) when the version it read went out of the server's hold meanwhile.
  bool map_gaussians(const MapGaussiansQuery& query, MapGaussians* output, int timeout_ms,
                     std::string* why);
  // Saves a map on the server, under its map_dir (`folder` empty: the map's name); `saved_to`
  // gets the server-side folder.
  bool save_map(const std::string& map_name, const std::string& folder, int timeout_ms,
                std::string* saved_to, std::string* why);
  // Post-trajectory refinement of a map no session streams into now, streamed in the server or
  // loaded with its keyframe images: `steps` steps over its stored keyframes, then a new version
  // (docs/protocol.md "Refinement").
  bool refine_map(const std::string& map_name, std::uint32_t steps, int timeout_ms, std::string* why);
  // Loads <map_dir>/<folder> on the server and serves it as `map_name`.
  bool load_map(const std::string& map_name, const std::string& folder, int timeout_ms,
                std::string* why);
  // This client's name on fslam/requests (host, process and instance).
  const std::string& id() const { return id_; }
  // Requests sent again because a new server matched, or no answer came in time (docs/protocol.md
  // "Resending").
  std::uint64_t resends() const { return resends_.load(std::memory_order_relaxed); }
  // An unanswered repeatable request goes again after kFirstResendMs, twice that, ... at most
  // kLastResendMs apart.
  static constexpr int kFirstResendMs = 1000, kLastResendMs = 8000;
  // Calls one client has waiting for answers at once (from several threads); one more fails at
  // once with an error. The server's reader keeps the newest 64 requests per client (reliable
  // delivery's history), so a larger burst, with its resends, would lose requests in DDS unseen.
  static constexpr std::size_t kMaxCallsInFlight = 32;

  // Callbacks run on the client's listener thread until the client is destroyed: what they
  // capture must outlive the client (declare it before the client), or the callback is cleared
  // first (on_pose(nullptr) and the others wait for a call in progress to return).
  // Called on the client's listener thread for every pose the server publishes.
  void on_pose(std::function<void(const PoseUpdate&)> callback);
  // Called on the listener thread for results addressed to this client that no call is waiting
  // for: frame errors and drops of the sessions it opened or pushed frames to.
  void on_result(std::function<void(const ResultUpdate&)> callback);
  // Called on the listener thread for every status report of any session.
  void on_status(std::function<void(const StatusUpdate&)> callback);
  // Called on the listener thread for every view pushed to a localise session this client
  // opened (SessionOptions::view_rate_hz); the newest one only when views come faster than it
  // returns.
  void on_view(std::function<void(const ViewUpdate&)> callback);
  // Writers and readers matched so far (for waiting on discovery).
  std::uint32_t matched_servers() const;

 private:
  struct Answer;
  void listen();
  bool control(const std::string& session, const std::string& map_name, bool open, bool attach_only,
               const SessionOptions& options, int timeout_ms, std::string* why, std::uint32_t refine_steps = 0);
  // Sends `sample` with `writer` once a server matched, and waits for the result (client, id);
  // sends it again, same id, whenever a new server reader matches before the answer came, and,
  // when `repeatable` (the server may run it twice), after kFirstResendMs, twice that, ... without
  // an answer: one sent before the server's result writer matched our reader is lost.
  bool call(dds_entity_t writer, const void* sample, const std::string& client, std::uint64_t id,
            const std::string& what, int timeout_ms, Answer* answer, std::string* why,
            bool repeatable = true);
  std::uint64_t new_request_id();
  // REQUEST_SAVE_MAP (save) or REQUEST_LOAD_MAP; server_folder (optional) gets the result's path.
  bool map_folder_request(bool save, const std::string& map_name, const std::string& folder,
                          int timeout_ms, std::string* server_folder, std::string* why);

  std::string id_;
  Entity participant_, frames_topic_, poses_topic_, control_topic_, results_topic_, status_topic_;
  Entity requests_topic_, frame_writer_, pose_reader_, control_writer_, request_writer_;
  Entity result_reader_, status_reader_, views_topic_, view_reader_, waitset_;
  std::string frames_refused_;  // why there is no frame writer (DDS Security), else empty
  std::mutex callback_mutex_;
  std::function<void(const PoseUpdate&)> pose_callback_;
  std::function<void(const ResultUpdate&)> result_callback_;
  std::function<void(const StatusUpdate&)> status_callback_;
  std::function<void(const ViewUpdate&)> view_callback_;
  std::condition_variable result_arrived_;
  std::map<std::pair<std::string, std::uint64_t>, std::unique_ptr<Answer>> awaited_;
  std::set<std::string> addresses_;  // result `client` values meant for us: id_ and our sessions
  // Apart from frame ids, which frame results echo: a result with an id from here that no call
  // awaits answers a resend of a call already answered, and is dropped.
  static constexpr std::uint64_t kFirstRequestId = 1ull << 62;
  std::uint64_t next_request_ = kFirstRequestId;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> resends_{0};
  std::thread listener_;
};

}  // namespace fslam::client
