#include "fslam/client/client.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <vector>

#include <unistd.h>

#include <opencv2/core/mat.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "depth_png.hpp"
#include "fslam/proto/types.h"

namespace fslam::client {
namespace {

bool fail(std::string* why, const std::string& message) {
  if (why) *why = message;
  return false;
}

}  // namespace

// What a waiting call gets from the listener thread.
struct Client::Answer {
  bool arrived = false;
  ResultUpdate result;
  RenderOutput render;
  std::string path;
  std::uint32_t gaussians_first = 0, gaussians_count = 0;  // REQUEST_MAP_GAUSSIANS
  std::vector<std::uint8_t> gaussians;
};

namespace {

std::string make_client_id() {
  static std::atomic<int> instances{0};
  char host[128] = "host";
  gethostname(host, sizeof host - 1);
  return std::string(host) + "/" + std::to_string(getpid()) + "/" + std::to_string(instances++);
}

// A result image as tightly packed rows (PNG payloads decoded, colour back to RGB).
bool decode_result_image(const fslam_proto_Image& in, RenderedImage* out) {
  out->width = in.width;
  out->height = in.height;
  out->channels = in.channels;
  out->bytes_per_channel = in.bytes_per_channel;
  if (in.data._buffer == nullptr) return false;
  if (in.encoding == fslam_proto_ENCODING_RAW) {
    out->pixels.assign(in.data._buffer, in.data._buffer + in.data._length);
    return out->pixels.size() ==
           static_cast<std::size_t>(in.width) * in.height * in.channels * in.bytes_per_channel;
  }
  const std::vector<std::uint8_t> bytes(in.data._buffer, in.data._buffer + in.data._length);
  cv::Mat image = cv::imdecode(bytes, cv::IMREAD_UNCHANGED);
  if (image.empty() || image.cols != static_cast<int>(in.width) ||
      image.rows != static_cast<int>(in.height) || image.channels() != in.channels ||
      static_cast<int>(image.elemSize1()) != in.bytes_per_channel) {
    return false;
  }
  if (image.channels() == 3) cv::cvtColor(image, image, cv::COLOR_BGR2RGB);
  out->pixels.assign(image.data, image.data + image.total() * image.elemSize());
  return true;
}

CameraIntrinsics from_wire(const fslam_proto_Intrinsics& k) {
  return {k.fx, k.fy, k.cx, k.cy, k.width, k.height};
}

void to_wire(const CameraView& view, fslam_proto_RenderRequest* r) {
  for (int k = 0; k < 3; ++k) r->T_world_camera.translation[k] = view.translation[k];
  for (int k = 0; k < 4; ++k) r->T_world_camera.rotation[k] = view.rotation[k];
  const CameraIntrinsics& k = view.intrinsics;
  r->intrinsics = {k.fx, k.fy, k.cx, k.cy, k.width, k.height};
  r->from_frame = view.from_frame;
  r->frame_id = view.frame_id;
}

// A sequence<float> on the wire that borrows `values`.
auto wire_floats(std::vector<float>& values) {
  return decltype(fslam_proto_SegmentRequest::points){static_cast<std::uint32_t>(values.size()),
                                                      static_cast<std::uint32_t>(values.size()),
                                                      values.data(), false};
}

// The fields every fslam/requests sample carries. `strings` owns what the sample points into
// and must outlive the write.
struct RequestStrings {
  std::string client, map, path;
};

void fill_request(RequestStrings* strings, std::uint64_t id, fslam_proto_RequestKind kind,
                  fslam_proto_Request* msg) {
  msg->client = strings->client.data();
  msg->request_id = id;
  msg->map_name = strings->map.data();
  msg->kind = kind;
  msg->path = strings->path.data();
}

// A result's or a view's images, pose and camera as a RenderOutput (images decoded); false
// with `why` when an image does not decode.
bool to_render_output(const dds_sequence_fslam_proto_Image& images, const fslam_proto_Pose& pose,
                      const fslam_proto_Intrinsics& intrinsics, RenderOutput* out, std::string* why) {
  for (std::uint32_t i = 0; i < images._length; ++i) {
    RenderedImage image;
    if (!decode_result_image(images._buffer[i], &image))
      return fail(why, "result image " + std::to_string(i) + " could not be decoded");
    out->images.push_back(std::move(image));
  }
  for (int k = 0; k < 3; ++k) out->translation[k] = pose.translation[k];
  for (int k = 0; k < 4; ++k) out->rotation[k] = pose.rotation[k];
  out->intrinsics = from_wire(intrinsics);
  return true;
}

// Images come in channel bit order (docs/protocol.md): gives each of `out`'s images its bit of
// `channels`; false when their count does not match.
bool label_channels(std::uint32_t channels, RenderOutput* out, std::string* why) {
  std::size_t next = 0;
  for (std::uint32_t bit = 1; bit <= kOpacity; bit <<= 1) {
    if ((channels & bit) != 0 && next < out->images.size()) out->images[next++].channel = bit;
  }
  if (next != out->images.size() || next == 0) {
    return fail(why, "the server sent " + std::to_string(out->images.size()) + " images for the channels asked");
  }
  return true;
}

}  // namespace

Client::Client(const ClientOptions& options) : id_(make_client_id()) {
  participant_ = make_participant(options.domain);
  const std::string& prefix = options.prefix;
  poses_topic_ = make_topic(participant_, &fslam_proto_PoseStamped_desc, prefix, "poses");
  control_topic_ = make_topic(participant_, &fslam_proto_SessionControl_desc, prefix, "session");
  results_topic_ = make_topic(participant_, &fslam_proto_Result_desc, prefix, "results");
  requests_topic_ = make_topic(participant_, &fslam_proto_Request_desc, prefix, "requests");
  status_topic_ = make_topic(participant_, &fslam_proto_SessionStatus_desc, prefix, "status");
  request_writer_ = make_writer(participant_, requests_topic_, Delivery::reliable);
  try {
    frames_topic_ = make_topic(participant_, &fslam_proto_Frame_desc, prefix, "frames");
    frame_writer_ = make_bounded_writer(participant_, frames_topic_, kFramesInFlight);
  } catch (const DdsError& e) {
    // DDS Security (configs/dds/secure.xml): a client whose permissions do not let it write
    // frames may still query maps; push_frame says why it cannot stream.
    if (e.code() != DDS_RETCODE_NOT_ALLOWED_BY_SECURITY) throw;
    frames_refused_ = e.what();
  }
  control_writer_ = make_writer(participant_, control_topic_, Delivery::reliable);
  pose_reader_ = make_reader(participant_, poses_topic_, Delivery::stream);
  result_reader_ = make_reader(participant_, results_topic_, Delivery::reliable);
  status_reader_ = make_reader(participant_, status_topic_, Delivery::best_effort);
  try {
    views_topic_ = make_topic(participant_, &fslam_proto_View_desc, prefix, "views");
    view_reader_ = make_reader(participant_, views_topic_, Delivery::newest);
  } catch (const DdsError& e) {
    // DDS Security permissions made before views existed: everything but views still works.
    if (e.code() != DDS_RETCODE_NOT_ALLOWED_BY_SECURITY) throw;
  }
  waitset_ = view_reader_ ? make_waitset(participant_, {&pose_reader_, &result_reader_, &status_reader_, &view_reader_})
                          : make_waitset(participant_, {&pose_reader_, &result_reader_, &status_reader_});
  addresses_.insert(id_);
  listener_ = std::thread([this] { listen(); });
}

Client::~Client() {
  stop_ = true;
  dds_waitset_set_trigger(waitset_.get(), true);
  if (listener_.joinable()) listener_.join();
}

void Client::on_pose(std::function<void(const PoseUpdate&)> callback) {
  std::lock_guard<std::mutex> lock(callback_mutex_);
  pose_callback_ = std::move(callback);
}

void Client::on_result(std::function<void(const ResultUpdate&)> callback) {
  std::lock_guard<std::mutex> lock(callback_mutex_);
  result_callback_ = std::move(callback);
}

void Client::on_status(std::function<void(const StatusUpdate&)> callback) {
  std::lock_guard<std::mutex> lock(callback_mutex_);
  status_callback_ = std::move(callback);
}

void Client::on_view(std::function<void(const ViewUpdate&)> callback) {
  std::lock_guard<std::mutex> lock(callback_mutex_);
  view_callback_ = std::move(callback);
}

bool Client::open_session(const std::string& session, const std::string& map_name, int timeout_ms,
                          std::string* why, const SessionOptions& options) {
  return control(session, map_name, true, false, options, timeout_ms, why);
}

bool Client::close_session(const std::string& session, int timeout_ms, std::string* why,
                           std::uint32_t refine_steps) {
  return control(session, "", false, false, {}, timeout_ms, why, refine_steps);
}

bool Client::attach_map(const std::string& map_name, int timeout_ms, std::string* why) {
  if (map_name.empty()) return fail(why, "attach: no map name");
  return control(id_, map_name, true, true, {}, timeout_ms, why);
}

std::uint64_t Client::new_request_id() {
  std::lock_guard<std::mutex> lock(callback_mutex_);
  return next_request_++;
}

bool Client::control(const std::string& session, const std::string& map_name, bool open,
                     bool attach_only, const SessionOptions& options, int timeout_ms, std::string* why,
                     std::uint32_t refine_steps) {
  const FramePolicy policy = options.policy;
  if (session.empty()) return fail(why, "session control: no session name");
  {
    std::lock_guard<std::mutex> lock(callback_mutex_);
    addresses_.insert(session);
  }
  fslam_proto_SessionControl msg{};
  std::string s = session, m = map_name;
  msg.session = s.data();
  msg.request_id = new_request_id();
  msg.command = open ? fslam_proto_SESSION_OPEN : fslam_proto_SESSION_CLOSE;
  msg.map_name = m.data();
  msg.attach_only = attach_only;
  msg.policy = policy == FramePolicy::live    ? fslam_proto_POLICY_LIVE
               : policy == FramePolicy::queue ? fslam_proto_POLICY_QUEUE
                                              : fslam_proto_POLICY_SERVER_DEFAULT;
  msg.mode = options.mode == SessionMode::localise ? fslam_proto_SESSION_LOCALISE
             : options.mode == SessionMode::extend ? fslam_proto_SESSION_EXTEND
                                                   : fslam_proto_SESSION_MAP;
  msg.view_rate_hz = static_cast<float>(options.view_rate_hz);
  msg.view_channels = options.view_channels;
  msg.refine_steps = refine_steps;
  const std::string what = attach_only ? "attach to map '" + map_name + "'"
                                       : std::string(open ? "open" : "close") + " session '" + session + "'";
  Answer answer;
  // Opening is repeatable (an open session answers OK again); a repeated close would answer
  // "unknown session" after the first closed it.
  const bool ok = call(control_writer_.get(), &msg, session, msg.request_id, what, timeout_ms, &answer, why, open);
  if (!open) {
    // The session's instances on our writers end with it, so that the server's readers free
    // theirs instead of keeping one per session ever opened (docs/reliability.md "Measured").
    dds_unregister_instance(control_writer_.get(), &msg);
    if (frame_writer_) {
      fslam_proto_Frame key{};
      key.session = s.data();
      dds_unregister_instance(frame_writer_.get(), &key);
    }
  }
  return ok;
}

bool Client::call(dds_entity_t writer, const void* sample, const std::string& client,
                  std::uint64_t id, const std::string& what, int timeout_ms, Answer* answer,
                  std::string* why, bool repeatable) {
  const auto key = std::make_pair(client, id);
  {
    std::lock_guard<std::mutex> lock(callback_mutex_);
    if (awaited_.size() >= kMaxCallsInFlight) {
      return fail(why, what + ": " + std::to_string(awaited_.size()) +
                           " calls of this client are waiting for answers (Client::kMaxCallsInFlight); "
                           "wait for one, or use another Client");
    }
    awaited_[key] = std::make_unique<Answer>();
  }
  // Wait for discovery both ways (a server's reader of the request and its writer of results:
  // results are volatile, so one sent before the server's writer matched our reader is lost),
  // then send and wait for the answer. When a new server reader matches meanwhile (the server
  // restarted, or another instance took over), the request goes again with the same id; so it
  // does, when repeatable, after 1, 2, 4, 8, 8, ... s without an answer: our side matching first
  // does not mean that the server's side has matched our reader (docs/protocol.md "Resending").
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
  dds_publication_matched_status_t matched{};
  dds_subscription_matched_status_t answering{};
  const auto both_matched = [&] {
    dds_get_publication_matched_status(writer, &matched);
    dds_get_subscription_matched_status(result_reader_.get(), &answering);
    return matched.current_count > 0 && answering.current_count > 0;
  };
  while (!both_matched() && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  bool sent = matched.current_count > 0 && dds_write(writer, sample) == DDS_RETCODE_OK;
  std::uint32_t readers_seen = matched.total_count;
  int resend_ms = kFirstResendMs;
  auto next_resend = std::chrono::steady_clock::now() + std::chrono::milliseconds(resend_ms);
  bool arrived = false;
  while (sent && !arrived) {
    const auto slice = std::min(deadline, std::chrono::steady_clock::now() + std::chrono::milliseconds(100));
    {
      std::unique_lock<std::mutex> lock(callback_mutex_);
      arrived = result_arrived_.wait_until(lock, slice, [&] { return awaited_[key]->arrived; });
    }
    const auto now = std::chrono::steady_clock::now();
    if (arrived || now >= deadline) break;
    const bool new_reader = both_matched() && matched.total_count > readers_seen;
    const bool overdue = repeatable && now >= next_resend && matched.current_count > 0;
    if (new_reader || overdue) {
      readers_seen = matched.total_count;
      resend_ms = std::min(2 * resend_ms, kLastResendMs);
      next_resend = now + std::chrono::milliseconds(resend_ms);
      if (dds_write(writer, sample) == DDS_RETCODE_OK) resends_.fetch_add(1, std::memory_order_relaxed);
    }
  }
  std::unique_lock<std::mutex> lock(callback_mutex_);
  arrived = arrived || awaited_[key]->arrived;
  std::unique_ptr<Answer> got = std::move(awaited_[key]);
  awaited_.erase(key);
  if (!arrived) {
    return fail(why, what + ": no answer from a server within " + std::to_string(timeout_ms) + " ms");
  }
  *answer = std::move(*got);
  if (!answer->result.ok) return fail(why, what + ": " + answer->result.error);
  return true;
}

bool Client::render(const RenderQuery& query, RenderOutput* output, int timeout_ms, std::string* why) {
  if (query.map_name.empty()) return fail(why, "render: no map name");
  fslam_proto_Request msg{};
  RequestStrings strings{id_, query.map_name, ""};
  const std::string& map = strings.map;
  fill_request(&strings, new_request_id(), fslam_proto_REQUEST_RENDER, &msg);
  to_wire(query, &msg.render);
  msg.render.channels = query.channels;
  msg.render.depth_scale = query.depth_scale;
  Answer answer;
  if (!call(request_writer_.get(), &msg, id_, msg.request_id, "render map '" + map + "'",
            timeout_ms, &answer, why)) {
    return false;
  }
  *output = std::move(answer.render);
  std::string reason;
  if (!label_channels(query.channels, output, &reason)) return fail(why, "render map '" + map + "': " + reason);
  return true;
}

bool Client::segment(const SegmentQuery& query, SegmentOutput* output, int timeout_ms,
                     std::string* why) {
  if (query.map_name.empty()) return fail(why, "segment: no map name");
  fslam_proto_Request msg{};
  RequestStrings strings{id_, query.map_name, ""};
  const std::string& map = strings.map;
  std::string text = query.text;
  std::vector<float> points = query.points, boxes = query.boxes;
  fill_request(&strings, new_request_id(), fslam_proto_REQUEST_SEGMENT, &msg);
  to_wire(query.view, &msg.render);
  fslam_proto_SegmentRequest& s = msg.segment;
  switch (query.mode) {
    case SegmentMode::points: s.mode = fslam_proto_SEGMENT_POINTS; break;
    case SegmentMode::boxes: s.mode = fslam_proto_SEGMENT_BOXES; break;
    case SegmentMode::text: s.mode = fslam_proto_SEGMENT_TEXT; break;
    default: s.mode = fslam_proto_SEGMENT_PROMPTLESS;
  }
  s.points = wire_floats(points);
  s.boxes = wire_floats(boxes);
  s.text = text.data();
  s.has_output_view = query.has_output_view;
  to_wire(query.output_view, &s.output_view);
  Answer answer;
  if (!call(request_writer_.get(), &msg, id_, msg.request_id, "segment map '" + map + "'",
            timeout_ms, &answer, why)) {
    return false;
  }
  RenderOutput& r = answer.render;
  if (r.images.size() != 2) {
    return fail(why, "segment map '" + map + "': the server sent " + std::to_string(r.images.size()) +
                         " images, expected labels and colour");
  }
  output->labels = std::move(r.images[0]);
  output->colour = std::move(r.images[1]);
  for (int k = 0; k < 3; ++k) output->translation[k] = r.translation[k];
  for (int k = 0; k < 4; ++k) output->rotation[k] = r.rotation[k];
  output->intrinsics = r.intrinsics;
  output->map_version = r.map_version;
  output->map_gaussians = r.map_gaussians;
  return true;
}

GaussianRecord unpack_gaussian(const std::uint8_t* record) {
  GaussianRecord g{};
  std::memcpy(g.mean, record, 12);  // little-endian float32, as the server writes them
  std::memcpy(g.scale, record + 12, 12);
  for (int k = 0; k < 4; ++k) g.rotation[k] = static_cast<std::int8_t>(record[24 + k]) / 127.0f;
  for (int c = 0; c < 3; ++c) g.rgb[c] = record[28 + c];
  g.opacity = record[31];
  return g;
}

bool Client::map_gaussians(const MapGaussiansQuery& query, MapGaussians* output, int timeout_ms,
                           std::string* why) {
  if (query.map_name.empty()) return fail(why, "map gaussians: no map name");
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
  *output = {};
  constexpr int kAttempts = 3;
  std::string last_error;
  for (int attempt = 0; attempt < kAttempts; ++attempt) {
    output->records.clear();
    std::uint64_t version = 0;  // 0: the first chunk begins a read at the newest version
    std::uint64_t total = 0;
    for (;;) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          deadline - std::chrono::steady_clock::now());
      if (left.count() <= 0) {
        return fail(why, "map gaussians of '" + query.map_name + "': not read within " +
                             std::to_string(timeout_ms) + " ms");
      }
      fslam_proto_Request msg{};
      RequestStrings strings{id_, query.map_name, ""};
      fill_request(&strings, new_request_id(), fslam_proto_REQUEST_MAP_GAUSSIANS, &msg);
      msg.since_version = query.since_version;
      msg.gaussians_version = version;
      msg.gaussians_first = static_cast<std::uint32_t>(output->records.size() / kGaussianRecordBytes);
      msg.gaussians_max = query.chunk_gaussians;
      Answer answer;
      ++output->requests;
      std::string call_why;
      if (!call(request_writer_.get(), &msg, id_, msg.request_id,
                "map gaussians of '" + query.map_name + "'", static_cast<int>(left.count()), &answer,
                &call_why)) {
        // A version that went out of the server's hold while we read it: start again.
        if (version != 0 && call_why.find("no longer held") != std::string::npos) {
          last_error = call_why;
          break;
        }
        return fail(why, call_why);
      }
      const RenderOutput& r = answer.render;
      if (version == 0 && r.map_version <= query.since_version) {
        output->version = r.map_version;
        output->count = r.map_gaussians;
        output->unchanged = true;
        return true;
      }
      if (answer.gaussians.size() != std::size_t{answer.gaussians_count} * kGaussianRecordBytes ||
          answer.gaussians_first != msg.gaussians_first || (version != 0 && r.map_version != version) ||
          (version != 0 && r.map_gaussians != total)) {
        return fail(why, "map gaussians of '" + query.map_name + "': the server sent an inconsistent chunk");
      }
      version = r.map_version;
      total = r.map_gaussians;
      output->records.insert(output->records.end(), answer.gaussians.begin(), answer.gaussians.end());
      const std::uint64_t have = output->records.size() / kGaussianRecordBytes;
      if (have == total) {
        output->version = version;
        output->count = total;
        return true;
      }
      if (answer.gaussians_count == 0) {
        return fail(why, "map gaussians of '" + query.map_name + "': the server sent an empty chunk");
      }
    }
  }
  return fail(why, last_error);
}

bool Client::save_map(const std::string& map_name, const std::string& folder, int timeout_ms,
                      std::string* saved_to, std::string* why) {
  return map_folder_request(true, map_name, folder, timeout_ms, saved_to, why);
}

bool Client::load_map(const std::string& map_name, const std::string& folder, int timeout_ms,
                      std::string* why) {
  return map_folder_request(false, map_name, folder, timeout_ms, nullptr, why);
}

bool Client::map_folder_request(bool save, const std::string& map_name, const std::string& folder,
                                int timeout_ms, std::string* server_folder, std::string* why) {
  fslam_proto_Request msg{};
  RequestStrings strings{id_, map_name, folder};
  fill_request(&strings, new_request_id(),
               save ? fslam_proto_REQUEST_SAVE_MAP : fslam_proto_REQUEST_LOAD_MAP, &msg);
  Answer answer;
  if (!call(request_writer_.get(), &msg, id_, msg.request_id,
            std::string(save ? "save" : "load") + " map '" + map_name + "'", timeout_ms, &answer,
            why)) {
    return false;
  }
  if (server_folder) *server_folder = answer.path;
  return true;
}

bool Client::refine_map(const std::string& map_name, std::uint32_t steps, int timeout_ms, std::string* why) {
  fslam_proto_Request msg{};
  RequestStrings strings{id_, map_name, ""};
  fill_request(&strings, new_request_id(), fslam_proto_REQUEST_REFINE_MAP, &msg);
  msg.refine_steps = steps;
  Answer answer;
  return call(request_writer_.get(), &msg, id_, msg.request_id, "refine map '" + map_name + "'", timeout_ms,
              &answer, why);
}

std::uint32_t Client::matched_servers() const {
  dds_publication_matched_status_t matched{};
  dds_get_publication_matched_status(frame_writer_ ? frame_writer_.get() : request_writer_.get(), &matched);
  return matched.current_count;
}

void Client::listen() {
  while (!stop_) {
    dds_attach_t triggered[3];
    dds_waitset_wait(waitset_.get(), triggered, 3, DDS_MSECS(200));
    take_each<fslam_proto_SessionStatus>(status_reader_.get(), [&](const fslam_proto_SessionStatus& st) {
      StatusUpdate update;
      update.session = st.session ? st.session : "";
      update.map_name = st.map_name ? st.map_name : "";
      update.last_drop_reason = st.last_drop_reason ? st.last_drop_reason : "";
      update.queue_depth = st.queue_depth;
      update.frames_received = st.frames_received;
      update.frames_processed = st.frames_processed;
      update.frames_dropped = st.frames_dropped;
      update.frames_skipped = st.frames_skipped;
      update.last_skip_reason = st.last_skip_reason ? st.last_skip_reason : "";
      update.frame_policy = st.frame_policy ? st.frame_policy : "";
      update.mode = st.mode ? st.mode : "";
      update.queue_ms_p50 = st.queue_ms_p50;
      update.queue_ms_p99 = st.queue_ms_p99;
      update.map_gaussians = st.map_gaussians;
      update.resident_bytes = st.resident_bytes;
      update.track_ms_p50 = st.track_ms_p50;
      update.track_ms_p99 = st.track_ms_p99;
      update.track_cpu_ms_p50 = st.track_cpu_ms_p50;
      update.track_cpu_ms_p99 = st.track_cpu_ms_p99;
      update.decode_ms_p50 = st.decode_ms_p50;
      update.decode_ms_p99 = st.decode_ms_p99;
      update.map_ms_p50 = st.map_ms_p50;
      update.map_ms_p99 = st.map_ms_p99;
      update.streaming = st.streaming;
      update.map_version = st.map_version;
      update.frames_tracked = st.frames_tracked;
      update.text_queries = st.text_queries;
      update.mapping_queue = st.mapping_queue;
      update.keyframes_left_out = st.keyframes_left_out;
      update.loop_closure = st.loop_closure;
      update.loops_closed = st.loops_closed;
      std::lock_guard<std::mutex> lock(callback_mutex_);
      if (status_callback_) status_callback_(update);
    });
    take_each<fslam_proto_Result>(result_reader_.get(), [&](const fslam_proto_Result& r) {
      ResultUpdate update;
      update.client = r.client ? r.client : "";
      update.request_id = r.request_id;
      update.map_name = r.map_name ? r.map_name : "";
      update.ok = r.status == fslam_proto_RESULT_OK;
      update.error = r.error ? r.error : "";
      std::lock_guard<std::mutex> lock(callback_mutex_);
      const auto waiting = awaited_.find({update.client, update.request_id});
      if (waiting != awaited_.end() && waiting->second && !waiting->second->arrived) {
        Answer& answer = *waiting->second;
        answer.path = r.path ? r.path : "";
        RenderOutput& out = answer.render;
        if (update.ok && !to_render_output(r.images, r.T_world_camera, r.intrinsics, &out, &update.error))
          update.ok = false;
        out.map_version = r.map_version;
        out.map_gaussians = r.map_gaussians;
        answer.gaussians_first = r.gaussians_first;
        answer.gaussians_count = r.gaussians_count;
        if (r.gaussians._buffer != nullptr) {
          answer.gaussians.assign(r.gaussians._buffer, r.gaussians._buffer + r.gaussians._length);
        }
        answer.result = update;
        answer.arrived = true;
        result_arrived_.notify_all();
      } else if (result_callback_ && update.request_id < kFirstRequestId && addresses_.count(update.client) != 0) {
        result_callback_(update);
      }
    });
    if (view_reader_) take_each<fslam_proto_View>(view_reader_.get(), [&](const fslam_proto_View& v) {
      ViewUpdate update;
      update.session = v.session ? v.session : "";
      {
        std::lock_guard<std::mutex> lock(callback_mutex_);
        if (!view_callback_ || addresses_.count(update.session) == 0) return;  // not our session's
      }
      update.map_name = v.map_name ? v.map_name : "";
      update.frame_id = v.frame_id;
      update.timestamp = v.timestamp;
      if (to_render_output(v.images, v.T_world_camera, v.intrinsics, &update.render, &update.error))
        label_channels(v.channels, &update.render, &update.error);
      update.render.map_version = v.map_version;
      update.render.map_gaussians = v.map_gaussians;
      std::lock_guard<std::mutex> lock(callback_mutex_);
      if (view_callback_) view_callback_(update);
    });
    take_each<fslam_proto_PoseStamped>(pose_reader_.get(), [&](const fslam_proto_PoseStamped& p) {
      PoseUpdate update;
      update.session = p.session ? p.session : "";
      update.frame_id = p.frame_id;
      update.timestamp = p.timestamp;
      for (int k = 0; k < 3; ++k) update.translation[k] = p.T_world_camera.translation[k];
      for (int k = 0; k < 4; ++k) update.rotation[k] = p.T_world_camera.rotation[k];
      update.state = static_cast<int>(p.state);
      update.skipped = p.state == fslam_proto_TRACKING_SKIPPED;
      update.note = p.note ? p.note : "";
      update.keyframe = p.keyframe;
      update.decode_ms = p.decode_ms;
      update.queue_ms = p.queue_ms;
      update.track_ms = p.track_ms;
      std::lock_guard<std::mutex> lock(callback_mutex_);
      if (pose_callback_) pose_callback_(update);
    });
  }
}

}  // namespace fslam::client
