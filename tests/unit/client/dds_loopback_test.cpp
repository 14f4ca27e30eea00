// A PoseStamped written on the loopback profile arrives intact: proves the IDL library, the RAII
// layer and the loopback-only Cyclone configuration together.
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "fslam/client/dds.hpp"
#include "fslam/proto/types.h"
#include "test_support.hpp"

namespace fslam::client {
namespace {

// Writes `sample` on a fresh reliable topic of type `desc` under a per-process prefix (loopback
// profile) and hands what arrives to `check`.
template <typename T, typename Check>
void round_trip(const dds_topic_descriptor_t* desc, const char* topic, const T& sample,
                Check check) {
  test::use_loopback_dds();
  const std::string prefix = "test" + std::to_string(getpid());
  Entity participant = make_participant(DDS_DOMAIN_DEFAULT);
  dds_qos_t* qos = dds_create_qos();
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_history(qos, DDS_HISTORY_KEEP_ALL, 0);
  Entity t(check_dds(dds_create_topic(participant.get(), desc, topic_name(prefix, topic).c_str(),
                                      qos, nullptr),
                     "create topic"));
  Entity reader(check_dds(dds_create_reader(participant.get(), t.get(), qos, nullptr), "reader"));
  Entity writer(check_dds(dds_create_writer(participant.get(), t.get(), qos, nullptr), "writer"));
  dds_delete_qos(qos);

  // Wait (bounded) until the writer has matched the reader.
  dds_publication_matched_status_t matched{};
  for (int i = 0; i < 500 && matched.current_count == 0; ++i) {
    dds_get_publication_matched_status(writer.get(), &matched);
    if (matched.current_count == 0) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ASSERT_GT(matched.current_count, 0u) << "writer never matched the reader on loopback";
  ASSERT_EQ(dds_write(writer.get(), &sample), DDS_RETCODE_OK);

  void* samples[1] = {nullptr};
  dds_sample_info_t info[1];
  int32_t n = 0;
  for (int i = 0; i < 500 && n <= 0; ++i) {
    n = dds_take(reader.get(), samples, info, 1, 1);
    if (n <= 0) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ASSERT_EQ(n, 1);
  check(*static_cast<const T*>(samples[0]));
  dds_return_loan(reader.get(), samples, n);
}

TEST(DdsLoopback, PoseRoundTrip) {
  fslam_proto_PoseStamped out{};
  char session[] = "kitchen";
  out.session = session;
  out.frame_id = 42;
  out.timestamp = 1.25;
  out.T_world_camera.translation[0] = 0.5;
  out.T_world_camera.rotation[3] = 1.0;
  out.state = fslam_proto_TRACKING_OK;
  out.keyframe = true;
  round_trip(&fslam_proto_PoseStamped_desc, "poses", out, [](const fslam_proto_PoseStamped& in) {
    EXPECT_STREQ(in.session, "kitchen");
    EXPECT_EQ(in.frame_id, 42u);
    EXPECT_DOUBLE_EQ(in.T_world_camera.translation[0], 0.5);
    EXPECT_EQ(in.state, fslam_proto_TRACKING_OK);
    EXPECT_TRUE(in.keyframe);
  });
}

// A render request and a result carrying two images survive the wire: the request/result
// contract of docs/protocol.md (the id and client are echoed, images arrive in order).
TEST(DdsLoopback, RequestAndResultRoundTrip) {
  fslam_proto_Request request{};
  char client[] = "viewer-1", map[] = "kitchen", path[] = "";
  request.client = client;
  request.request_id = 7;
  request.map_name = map;
  request.kind = fslam_proto_REQUEST_RENDER;
  request.render.T_world_camera.rotation[3] = 1.0;
  request.render.intrinsics = {525.f, 525.f, 319.5f, 239.5f, 640, 480};
  request.render.channels = fslam_proto_CHANNEL_COLOUR | fslam_proto_CHANNEL_DEPTH;
  request.render.depth_scale = 1000.f;
  request.path = path;
  round_trip(&fslam_proto_Request_desc, "requests", request, [](const fslam_proto_Request& in) {
    EXPECT_STREQ(in.client, "viewer-1");
    EXPECT_EQ(in.request_id, 7u);
    EXPECT_EQ(in.kind, fslam_proto_REQUEST_RENDER);
    EXPECT_EQ(in.render.intrinsics.width, 640u);
    EXPECT_EQ(in.render.channels, 3u);
  });

  fslam_proto_Result result{};
  char error[] = "";
  result.client = client;
  result.request_id = 7;
  result.map_name = map;
  result.status = fslam_proto_RESULT_OK;
  result.error = error;
  result.map_version = 12;
  std::vector<uint8_t> colour(4 * 3, 200), depth(4 * 2, 9);
  fslam_proto_Image images[2] = {};
  images[0] = {fslam_proto_ENCODING_RAW, 2, 2, 3, 1, {}};
  images[0].data = {static_cast<uint32_t>(colour.size()), static_cast<uint32_t>(colour.size()),
                    colour.data(), false};
  images[1] = {fslam_proto_ENCODING_RAW, 2, 2, 1, 2, {}};
  images[1].data = {static_cast<uint32_t>(depth.size()), static_cast<uint32_t>(depth.size()),
                    depth.data(), false};
  result.images = {2, 2, images, false};
  round_trip(&fslam_proto_Result_desc, "results", result, [](const fslam_proto_Result& in) {
    EXPECT_EQ(in.request_id, 7u);
    EXPECT_EQ(in.status, fslam_proto_RESULT_OK);
    EXPECT_EQ(in.map_version, 12u);
    ASSERT_EQ(in.images._length, 2u);
    EXPECT_EQ(in.images._buffer[0].channels, 3);
    EXPECT_EQ(in.images._buffer[1].bytes_per_channel, 2);
    ASSERT_EQ(in.images._buffer[1].data._length, 8u);
    EXPECT_EQ(in.images._buffer[1].data._buffer[7], 9);
  });
}

TEST(DdsLoopback, ErrorsCarryTheirContext) {
  try {
    check_dds(DDS_RETCODE_BAD_PARAMETER, "create reader");
    FAIL() << "expected a DdsError";
  } catch (const DdsError& e) {
    EXPECT_NE(std::string(e.what()).find("create reader"), std::string::npos);
    EXPECT_EQ(e.code(), DDS_RETCODE_BAD_PARAMETER);
  }
  EXPECT_EQ(topic_name("", "frames"), "fslam/frames");
  EXPECT_EQ(topic_name("t1", "frames"), "t1/frames");
}

}  // namespace
}  // namespace fslam::client
