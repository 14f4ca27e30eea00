// The thin client against a stand-in server on the loopback profile: frames arrive with their
// payloads intact (depth lossless), poses come back through the callback, bad frames are
// refused before they reach the wire.
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <map>
#include <mutex>
#include <set>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core/mat.hpp>
#include <opencv2/imgcodecs.hpp>

#include "fslam/client/client.hpp"
#include "fslam/proto/types.h"
#include "test_support.hpp"

namespace fslam::client {
namespace {

constexpr int kW = 64, kH = 48;

struct TestFrame {
  std::vector<std::uint8_t> rgb = std::vector<std::uint8_t>(kW * kH * 3);
  std::vector<std::uint16_t> depth = std::vector<std::uint16_t>(kW * kH);
  FrameInput input;
  explicit TestFrame(std::uint64_t id) {
    for (int i = 0; i < kW * kH; ++i) {
      rgb[3 * i] = static_cast<std::uint8_t>(i % 251);
      rgb[3 * i + 1] = static_cast<std::uint8_t>(id * 7);
      rgb[3 * i + 2] = 40;
      depth[i] = static_cast<std::uint16_t>(i % 7 == 0 ? 0 : 1000 + i + id);  // with holes
    }
    input.frame_id = id;
    input.timestamp = static_cast<double>(id) / 30.0;
    input.intrinsics = {50.f, 50.f, 31.5f, 23.5f, kW, kH};
    input.rgb = rgb.data();
    input.depth = depth.data();
  }
};

TEST(Client, FramesReachAServerAndPosesComeBack) {
  test::use_loopback_dds();
  const std::string prefix = "client" + std::to_string(getpid());
  // The stand-in server: reads frames, checks the depth payload, answers with a pose.
  Entity participant = make_participant(DDS_DOMAIN_DEFAULT);
  dds_qos_t* qos = dds_create_qos();
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 64);
  Entity frames(check_dds(dds_create_topic(participant.get(), &fslam_proto_Frame_desc,
                                           topic_name(prefix, "frames").c_str(), qos, nullptr), "t"));
  Entity poses(check_dds(dds_create_topic(participant.get(), &fslam_proto_PoseStamped_desc,
                                          topic_name(prefix, "poses").c_str(), qos, nullptr), "t"));
  Entity frame_reader(check_dds(dds_create_reader(participant.get(), frames.get(), qos, nullptr), "r"));
  Entity pose_writer(check_dds(dds_create_writer(participant.get(), poses.get(), qos, nullptr), "w"));
  dds_delete_qos(qos);

  ClientOptions options;
  options.prefix = prefix;
  std::mutex mutex;  // outlives the client, whose listener thread calls the callback
  std::set<std::uint64_t> received;
  Client client(options);
  client.on_pose([&](const PoseUpdate& p) {
    std::lock_guard<std::mutex> lock(mutex);
    EXPECT_EQ(p.session, "kitchen");
    EXPECT_DOUBLE_EQ(p.translation[0], 0.01 * static_cast<double>(p.frame_id));
    received.insert(p.frame_id);
  });
  for (int i = 0; i < 500 && client.matched_servers() == 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  ASSERT_GT(client.matched_servers(), 0u) << "the client never matched the server on loopback";
  dds_subscription_matched_status_t sub{};
  for (int i = 0; i < 500 && sub.current_count == 0; ++i) {
    dds_get_subscription_matched_status(frame_reader.get(), &sub);
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }

  constexpr int kFrames = 10;
  for (int f = 0; f < kFrames; ++f) {
    TestFrame frame(static_cast<std::uint64_t>(f));
    frame.input.colour_encoding = f % 2 == 0 ? PayloadEncoding::jpeg : PayloadEncoding::raw;
    std::string why;
    if (f % 3 == 0) {  // encoded ahead, then published: the same frame on the wire
      EncodedFrame encoded;
      ASSERT_TRUE(Client::encode_frame(frame.input, &encoded, &why)) << why;
      ASSERT_TRUE(client.push_encoded("kitchen", encoded, &why)) << why;
    } else {
      ASSERT_TRUE(client.push_frame("kitchen", frame.input, &why)) << why;
    }
  }
  int served = 0;
  for (int spin = 0; spin < 500 && served < kFrames; ++spin) {
    void* samples[4] = {nullptr};
    dds_sample_info_t info[4];
    const int32_t n = dds_take(frame_reader.get(), samples, info, 4, 4);
    if (n <= 0) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
      continue;
    }
    for (int32_t i = 0; i < n; ++i) {
      if (!info[i].valid_data) continue;
      const auto* msg = static_cast<const fslam_proto_Frame*>(samples[i]);
      TestFrame expected(msg->frame_id);
      EXPECT_EQ(msg->depth.encoding, fslam_proto_ENCODING_PNG);
      const std::vector<std::uint8_t> png(msg->depth.data._buffer,
                                          msg->depth.data._buffer + msg->depth.data._length);
      const cv::Mat depth = cv::imdecode(png, cv::IMREAD_UNCHANGED);
      ASSERT_EQ(depth.type(), CV_16UC1);
      EXPECT_EQ(0, std::memcmp(depth.data, expected.depth.data(), expected.depth.size() * 2))
          << "depth must arrive bit-exact";
      EXPECT_FLOAT_EQ(msg->intrinsics.fx, 50.f);
      fslam_proto_PoseStamped pose{};
      pose.session = msg->session;
      pose.frame_id = msg->frame_id;
      pose.timestamp = msg->timestamp;
      pose.T_world_camera.translation[0] = 0.01 * static_cast<double>(msg->frame_id);
      pose.T_world_camera.rotation[3] = 1.0;
      pose.state = fslam_proto_TRACKING_OK;
      ASSERT_EQ(dds_write(pose_writer.get(), &pose), DDS_RETCODE_OK);
      ++served;
    }
    dds_return_loan(frame_reader.get(), samples, n);
  }
  EXPECT_EQ(served, kFrames);
  for (int i = 0; i < 500; ++i) {
    {
      std::lock_guard<std::mutex> lock(mutex);
      if (received.size() == static_cast<std::size_t>(kFrames)) break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  std::lock_guard<std::mutex> lock(mutex);
  EXPECT_EQ(received.size(), static_cast<std::size_t>(kFrames));
}

TEST(Client, RefusesBadFramesWithAReason) {
  test::use_loopback_dds();
  ClientOptions options;
  options.prefix = "clientbad" + std::to_string(getpid());
  Client client(options);
  std::string why;
  TestFrame frame(1);
  EXPECT_FALSE(client.push_frame("", frame.input, &why));
  EXPECT_NE(why.find("session"), std::string::npos);
  frame.input.intrinsics.fx = 0;
  EXPECT_FALSE(client.push_frame("s", frame.input, &why));
  EXPECT_NE(why.find("intrinsics"), std::string::npos);
  frame.input.intrinsics.fx = std::nanf("");
  EXPECT_FALSE(client.push_frame("s", frame.input, &why));
  TestFrame lossy(2);
  lossy.input.depth_encoding = PayloadEncoding::jpeg;
  EXPECT_FALSE(client.push_frame("s", lossy.input, &why));
  EXPECT_NE(why.find("lossless"), std::string::npos);
  TestFrame missing(3);
  missing.input.depth = nullptr;
  EXPECT_FALSE(client.push_frame("s", missing.input, &why));
  EncodedFrame unused;
  EXPECT_FALSE(Client::encode_frame(missing.input, &unused, &why));
  EXPECT_NE(why.find("required"), std::string::npos);

  // Encoded frames: the same checks of the header, and both payloads present.
  TestFrame good(4);
  EncodedFrame encoded;
  ASSERT_TRUE(Client::encode_frame(good.input, &encoded, &why)) << why;
  EXPECT_FALSE(client.push_encoded("", encoded, &why));
  EXPECT_NE(why.find("session"), std::string::npos);
  EncodedFrame no_depth = encoded;
  no_depth.depth.clear();
  EXPECT_FALSE(client.push_encoded("s", no_depth, &why));
  EXPECT_NE(why.find("required"), std::string::npos);
  EncodedFrame zero_scale = encoded;
  zero_scale.depth_scale = 0.0f;
  EXPECT_FALSE(client.push_encoded("s", zero_scale, &why));
  EXPECT_NE(why.find("scale"), std::string::npos);
  EncodedFrame lossy_depth = encoded;
  lossy_depth.depth_encoding = PayloadEncoding::jpeg;
  EXPECT_FALSE(client.push_encoded("s", lossy_depth, &why));
  EXPECT_NE(why.find("lossless"), std::string::npos);
  EncodedFrame no_size = encoded;
  no_size.intrinsics.width = 0;
  EXPECT_FALSE(client.push_encoded("s", no_size, &why));
  EXPECT_NE(why.find("intrinsics"), std::string::npos);
}

// encode_frame's payloads are ordinary files: the depth PNG decodes to the same 16-bit values,
// the JPEG colour to within JPEG's error of the RGB rows (OpenCV decodes to BGR): a smooth
// image, as JPEG's 4:2:0 chroma would blur TestFrame's sawtooth.
TEST(Client, EncodedFramesDecodeToTheirImages) {
  TestFrame frame(5);
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      std::uint8_t* p = frame.rgb.data() + 3 * (y * kW + x);
      p[0] = static_cast<std::uint8_t>(3 * x);
      p[1] = static_cast<std::uint8_t>(200 - 3 * y);
      p[2] = 60;
    }
  }
  EncodedFrame encoded;
  std::string why;
  ASSERT_TRUE(Client::encode_frame(frame.input, &encoded, &why)) << why;
  EXPECT_EQ(encoded.frame_id, 5u);
  EXPECT_DOUBLE_EQ(encoded.timestamp, 5.0 / 30.0);
  EXPECT_EQ(encoded.intrinsics.width, static_cast<std::uint32_t>(kW));
  const cv::Mat depth = cv::imdecode(encoded.depth, cv::IMREAD_UNCHANGED);
  ASSERT_EQ(depth.type(), CV_16UC1);
  ASSERT_EQ(depth.size(), cv::Size(kW, kH));
  EXPECT_TRUE(std::equal(frame.depth.begin(), frame.depth.end(), depth.ptr<std::uint16_t>()));
  const cv::Mat bgr = cv::imdecode(encoded.colour, cv::IMREAD_COLOR);
  ASSERT_EQ(bgr.size(), cv::Size(kW, kH));
  double error = 0.0;  // mean absolute error, 8-bit levels
  for (int i = 0; i < kW * kH; ++i)
    for (int c = 0; c < 3; ++c) error += std::abs(bgr.data[3 * i + 2 - c] - frame.rgb[3 * i + c]);
  EXPECT_LT(error / (kW * kH * 3), 3.0);
}

// A stand-in server that drops the first copy of every request, as a server whose result writer
// had not yet matched the client's reader loses its first answer: the client sends the request
// again, same id, without an answer after Client::kFirstResendMs, and the call gets the answer
// (docs/protocol.md "Resending"). A close is not repeatable and is not resent.
TEST(Client, AnUnansweredRequestIsSentAgainWithItsId) {
  test::use_loopback_dds();
  const std::string prefix = "clientresend" + std::to_string(getpid());
  Entity participant = make_participant(DDS_DOMAIN_DEFAULT);
  Entity requests = make_topic(participant, &fslam_proto_Request_desc, prefix, "requests");
  Entity controls = make_topic(participant, &fslam_proto_SessionControl_desc, prefix, "session");
  Entity results = make_topic(participant, &fslam_proto_Result_desc, prefix, "results");
  Entity request_reader = make_reader(participant, requests, Delivery::reliable);
  Entity control_reader = make_reader(participant, controls, Delivery::reliable);
  Entity result_writer = make_writer(participant, results, Delivery::reliable);
  std::mutex mutex;
  std::map<std::uint64_t, int> copies;  // request id -> copies seen
  std::atomic<bool> stop{false};
  std::thread server([&] {
    while (!stop) {
      const auto answer_second = [&](const char* client, std::uint64_t id) {
        int seen = 0;
        {
          std::lock_guard<std::mutex> lock(mutex);
          seen = ++copies[id];
        }
        if (seen < 2) return;  // the first copy's answer is "lost"
        fslam_proto_Result r{};
        char error[] = "stand-in answers the second copy", empty[] = "";
        r.client = const_cast<char*>(client);
        r.request_id = id;
        r.map_name = empty;
        r.status = fslam_proto_RESULT_ERROR;
        r.error = error;
        r.path = empty;
        dds_write(result_writer.get(), &r);
      };
      take_each<fslam_proto_Request>(request_reader.get(),
                                     [&](const fslam_proto_Request& m) { answer_second(m.client, m.request_id); });
      take_each<fslam_proto_SessionControl>(control_reader.get(), [&](const fslam_proto_SessionControl& m) {
        answer_second(m.session, m.request_id);
      });
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  });
  ClientOptions options;
  options.prefix = prefix;
  Client client(options);
  std::string why;
  RenderQuery q;
  q.map_name = "room";
  RenderOutput out;
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_FALSE(client.render(q, &out, 10000, &why));
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_NE(why.find("stand-in answers the second copy"), std::string::npos) << why;
  EXPECT_GE(client.resends(), 1u);
  EXPECT_LT(s, 5.0) << "the resend should go after about " << Client::kFirstResendMs << " ms";
  EXPECT_FALSE(client.open_session("s", "room", 10000, &why));
  EXPECT_NE(why.find("stand-in answers the second copy"), std::string::npos) << why;
  // A close goes once: the stand-in never answers it.
  const std::uint64_t before = client.resends();
  EXPECT_FALSE(client.close_session("s", 2500, &why));
  EXPECT_NE(why.find("no answer"), std::string::npos) << why;
  EXPECT_EQ(client.resends(), before);
  stop = true;
  server.join();
}

// More calls waiting at once than Client::kMaxCallsInFlight (threads sharing one client) fail at
// once with an error that says so, instead of overflowing the server's per-client request history
// in DDS, where they would be lost unseen. No server runs: the calls in flight time out.
TEST(Client, CallsBeyondTheInFlightBoundFailAtOnce) {
  test::use_loopback_dds();
  ClientOptions options;
  options.prefix = "clientinflight" + std::to_string(getpid());
  Client client(options);
  constexpr int kExtra = 8, kTimeoutMs = 3000;
  constexpr int kCalls = static_cast<int>(Client::kMaxCallsInFlight) + kExtra;
  std::mutex mutex;
  int refused = 0, unanswered = 0;
  double slowest_refusal_s = 0;
  std::vector<std::thread> threads;
  for (int i = 0; i < kCalls; ++i) {
    threads.emplace_back([&] {
      RenderQuery q;
      q.map_name = "room";
      RenderOutput out;
      std::string why;
      const auto t0 = std::chrono::steady_clock::now();
      const bool ok = client.render(q, &out, kTimeoutMs, &why);
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      std::lock_guard<std::mutex> lock(mutex);
      EXPECT_FALSE(ok);
      if (why.find("kMaxCallsInFlight") != std::string::npos) {
        ++refused;
        slowest_refusal_s = std::max(slowest_refusal_s, s);
      } else if (why.find("no answer") != std::string::npos) {
        ++unanswered;
      } else {
        ADD_FAILURE() << why;
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(refused, kExtra);
  EXPECT_EQ(unanswered, static_cast<int>(Client::kMaxCallsInFlight));
  EXPECT_LT(slowest_refusal_s, 1.0) << "a refusal must not wait for the calls in flight";
}

// A stream's DDS instance is its session (client for requests and results), never one frame or
// request: Cyclone keeps every instance a writer ever wrote for the writer's life, so a key per
// frame grew the server by ~1.4 KB per pose in the soak (docs/reliability.md). Two frame ids of
// one session map to one instance handle; another session to another.
TEST(Client, OneDdsInstancePerSessionNotPerFrame) {
  test::use_loopback_dds();
  const std::string prefix = "clientinstances" + std::to_string(getpid());
  Entity participant = make_participant(DDS_DOMAIN_DEFAULT);
  const auto handles = [&](const dds_topic_descriptor_t* desc, const char* name, void* a, void* b,
                           void* other) {
    Entity topic = make_topic(participant, desc, prefix, name);
    Entity writer = make_writer(participant, topic, Delivery::reliable);
    dds_instance_handle_t ha = 0, hb = 0, ho = 0;
    EXPECT_EQ(dds_register_instance(writer.get(), &ha, a), DDS_RETCODE_OK) << name;
    EXPECT_EQ(dds_register_instance(writer.get(), &hb, b), DDS_RETCODE_OK) << name;
    EXPECT_EQ(dds_register_instance(writer.get(), &ho, other), DDS_RETCODE_OK) << name;
    EXPECT_EQ(ha, hb) << name << ": two frame (request) ids of one stream must be one instance";
    EXPECT_NE(ha, ho) << name << ": two streams must be two instances";
  };
  char s1[] = "s1", s2[] = "s2", empty[] = "";
  fslam_proto_Frame fa{}, fb{}, fo{};
  fa.session = fb.session = s1;
  fo.session = s2;
  fa.frame_id = 1;
  fb.frame_id = fo.frame_id = 2;
  handles(&fslam_proto_Frame_desc, "frames", &fa, &fb, &fo);
  fslam_proto_PoseStamped pa{}, pb{}, po{};
  pa.session = pb.session = s1;
  po.session = s2;
  pa.note = pb.note = po.note = empty;
  pa.frame_id = 1;
  pb.frame_id = po.frame_id = 2;
  handles(&fslam_proto_PoseStamped_desc, "poses", &pa, &pb, &po);
  fslam_proto_Request ra{}, rb{}, ro{};
  ra.client = rb.client = s1;
  ro.client = s2;
  ra.map_name = rb.map_name = ro.map_name = ra.path = rb.path = ro.path = empty;
  ra.segment.text = rb.segment.text = ro.segment.text = empty;
  ra.request_id = 1;
  rb.request_id = ro.request_id = 2;
  handles(&fslam_proto_Request_desc, "requests", &ra, &rb, &ro);
  fslam_proto_Result qa{}, qb{}, qo{};
  qa.client = qb.client = s1;
  qo.client = s2;
  qa.map_name = qb.map_name = qo.map_name = qa.error = qb.error = qo.error = qa.path = qb.path = qo.path = empty;
  qa.request_id = 1;
  qb.request_id = qo.request_id = 2;
  handles(&fslam_proto_Result_desc, "results", &qa, &qb, &qo);
}

}  // namespace
}  // namespace fslam::client
