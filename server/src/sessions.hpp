// The streaming sessions of a server (docs/protocol.md): opened and closed by fslam/session
// control samples, each with its frame policy, its waiting frames and its threads. Frames follow
// the session's policy: live (the default) tracks the newest frame and skips older waiting ones,
// reporting each skip on the pose stream; queue tracks every frame from a bounded queue whose
// overflow drops the newest with an error result.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "fslam/core/pipeline/slam_pipeline.hpp"
#include "fslam/proto/types.h"
#include "fslam/server/mapping_thread.hpp"
#include "fslam/server/server.hpp"
#include "fslam/server/wire.hpp"
#include "view_stream.hpp"

namespace fslam::server {

struct MapEntry;
class MapRegistry;
class Counters;

// What fslam/status says about one session: its counts and timings in `numbers`, whose strings
// the fields below fill (they stay valid while the report lives).
struct SessionReport {
  fslam_proto_SessionStatus numbers{};
  std::string session, map_name, frame_policy, mode, last_drop_reason, last_skip_reason;
  std::shared_ptr<MapEntry> map;
};

class Sessions {
 public:
  using Log = std::function<void(const std::string&)>;
  // All references must outlive the sessions.
  // `view_rasterizer` renders the views of localise sessions that ask for them.
  Sessions(const ServerConfig& config, MapRegistry& maps, const Replies& replies, Counters& counters,
           const core::Rasterizer& view_rasterizer, Log log);
  ~Sessions();

  // A fslam/session sample: open (a new map, localising in a served one, or extending one), close
  // (drain, then answer), or attach only.
  void handle_control(const fslam_proto_SessionControl& msg);
  // A fslam/frames sample: checked, then queued by its session's policy (or refused with a result).
  void handle_frame(const fslam_proto_Frame& msg);
  // Scale-out (map_directory.hpp): stops serving a map another instance holds by the claim
  // rule; its sessions (streaming and localising) are closed with an error result saying why.
  void withdraw_map(const std::string& name, const std::string& reason);
  // Closes, as a SESSION_CLOSE would, every session that received no frame for `lease_s`
  // seconds (server.session_lease_s: its client died or stopped streaming); maps stay served.
  void close_idle(double lease_s);
  // Lets every session track what it accepted, then stops them all (deactivate).
  void close_all();
  std::size_t count() const;
  std::vector<SessionReport> reports() const;

  // In-process sessions (Server::open_session and friends, for the ROS 2 bridge).
  // True when `session` is open and streams into `map`.
  bool streams_into(const std::string& session, const std::string& map) const;
  // server.session_lease_s no longer closes `session`: the server feeds it (a ROS camera may
  // pause for longer than the lease, and nothing would open the session again).
  void exempt_from_lease(const std::string& session);
  // A frame its source could not build: counted and reported as a refused fslam/frames sample.
  void report_rejected(const std::string& session, const std::string& message);
  // Called on a session's tracking thread after each pose it publishes; empty: none.
  void set_pose_listener(std::function<void(const Server::TrackedPose&)> listener);

 private:
  struct QueuedFrame;
  struct PreparedFrame;
  struct Session;

  void open_session(const fslam_proto_SessionControl& msg, const std::string& name,
                    const std::string& map_name);
  // SESSION_LOCALISE: a tracking-only pipeline fixed on the newest version of a served map and
  // its keyframe descriptions; null with `why` when the map cannot be localised in.
  std::shared_ptr<core::SlamPipeline> make_localiser(const std::string& map_name, std::shared_ptr<MapEntry>* map,
                                                     std::string* why) const;
  // SESSION_EXTEND: a streaming pipeline whose mapper continues `map`'s newest version (and its
  // version numbers) and whose tracker relocalises its first frame against the map's keyframes.
  std::shared_ptr<core::SlamPipeline> make_extender(MapEntry& map, std::string* why) const;
  // What a session started in `map` needs: Gaussians and keyframe descriptions; `verb` says what
  // for in the error.
  bool startable(MapEntry& map, const std::string& verb, core::MapVersions::Version* version,
                 std::shared_ptr<const std::vector<core::DescribedKeyframe>>* keyframes, std::string* why) const;
  std::shared_ptr<core::SlamPipeline> make_pipeline(std::string* why) const;
  void start_threads(Session* session);
  // Drains `session` on a closer thread, refines its map `refine_steps` steps (0: not), then
  // answers (client, request_id) with `answer` (empty: OK) or the refinement's error.
  void close_later(std::unique_ptr<Session> session, std::string client, std::uint64_t request_id,
                   std::string answer = "", std::uint32_t refine_steps = 0);
  // Starts `work` on a closer thread; joins the closers that have finished (so that sessions
  // opened and closed without end do not pile up threads).
  void start_closer(const std::shared_ptr<Session>& session, std::function<void()> work);
  void finish_session(Session* session);
  // A session's frame threads: decode + prepare (features, source Gaussians), then register;
  // or one thread doing both (server.pipelined_tracking false).
  static void run_on_one_thread(const std::function<void()>& work);
  void prepare_frames(Session* session);
  void track_frames(Session* session);
  void prepare_and_track_frames(Session* session);
  bool next_queued(Session* session, bool room, QueuedFrame* queued);
  bool prepare_one(Session* session, QueuedFrame&& queued, PreparedFrame* prepared);
  void track_one(Session* session, PreparedFrame&& prepared);
  // A frame refused before its session's policy (unknown session, bad frame, or from the ROS 2
  // bridge): counted as rejected, on the session's status when it is open, and answered.
  // mutex_ held; the caller counted it as received.
  void reject_locked(Session* session, const char* client, std::uint64_t frame_id, const std::string& map,
                     const std::string& message);
  // An accepted frame the session does not take (rate limit, full queue): counted and answered.
  // The session's mutex held.
  void drop_locked(Session* session, const fslam_proto_Frame& msg, std::string reason);

  const ServerConfig& config_;
  MapRegistry& maps_;
  const Replies& replies_;
  Counters& counters_;
  const core::Rasterizer& view_rasterizer_;
  Log log_;
  mutable std::mutex mutex_;  // guards everything below
  std::map<std::string, std::unique_ptr<Session>> sessions_;
  struct Closer {
    std::thread thread;
    std::shared_ptr<std::atomic<bool>> done;
    std::weak_ptr<Session> session;  // the one it drains (shutdown hurries its mapper)
  };
  std::vector<Closer> closers_;  // sessions being drained after a close
  mutable std::mutex listener_mutex_;
  std::function<void(const Server::TrackedPose&)> pose_listener_;
};

}  // namespace fslam::server
