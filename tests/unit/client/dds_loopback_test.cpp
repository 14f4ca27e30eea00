// A PoseStamped written on the loopback profile arrives intact: proves the IDL library, the RAII
// layer and the loopback-only Cyclone configuration together.
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <thread>

#include <gtest/gtest.h>

#include "fslam/client/dds.hpp"
#include "fslam/proto/types.h"
#include "test_support.hpp"

namespace fslam::client {
namespace {

TEST(DdsLoopback, PoseRoundTrip) {
  test::use_loopback_dds();
  const std::string prefix = "test" + std::to_string(getpid());
  Entity participant = make_participant(DDS_DOMAIN_DEFAULT);
  dds_qos_t* qos = dds_create_qos();
  dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
  dds_qset_history(qos, DDS_HISTORY_KEEP_ALL, 0);
  Entity topic(check_dds(dds_create_topic(participant.get(), &fslam_proto_PoseStamped_desc,
                                          topic_name(prefix, "poses").c_str(), qos, nullptr),
                         "create topic"));
  Entity reader(check_dds(dds_create_reader(participant.get(), topic.get(), qos, nullptr), "reader"));
  Entity writer(check_dds(dds_create_writer(participant.get(), topic.get(), qos, nullptr), "writer"));
  dds_delete_qos(qos);

  // Wait (bounded) until the writer has matched the reader.
  dds_publication_matched_status_t matched{};
  for (int i = 0; i < 500 && matched.current_count == 0; ++i) {
    dds_get_publication_matched_status(writer.get(), &matched);
    if (matched.current_count == 0) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ASSERT_GT(matched.current_count, 0u) << "writer never matched the reader on loopback";

  fslam_proto_PoseStamped out{};
  char session[] = "kitchen";
  out.session = session;
  out.frame_id = 42;
  out.timestamp = 1.25;
  out.T_world_camera.translation[0] = 0.5;
  out.T_world_camera.rotation[3] = 1.0;
  out.state = fslam_proto_TRACKING_OK;
  out.keyframe = true;
  ASSERT_EQ(dds_write(writer.get(), &out), DDS_RETCODE_OK);

  void* samples[1] = {nullptr};
  dds_sample_info_t info[1];
  int32_t n = 0;
  for (int i = 0; i < 500 && n <= 0; ++i) {
    n = dds_take(reader.get(), samples, info, 1, 1);
    if (n <= 0) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ASSERT_EQ(n, 1);
  const auto* in = static_cast<const fslam_proto_PoseStamped*>(samples[0]);
  EXPECT_STREQ(in->session, "kitchen");
  EXPECT_EQ(in->frame_id, 42u);
  EXPECT_DOUBLE_EQ(in->T_world_camera.translation[0], 0.5);
  EXPECT_EQ(in->state, fslam_proto_TRACKING_OK);
  EXPECT_TRUE(in->keyframe);
  dds_return_loan(reader.get(), samples, n);
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
