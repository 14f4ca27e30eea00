// A small RAII layer over the Cyclone DDS C API, shared by every featureslam process.
#pragma once

#include <initializer_list>
#include <stdexcept>
#include <string>
#include <utility>

#include <dds/dds.h>

namespace fslam::client {

// Raised when a DDS call fails; caught at the session or main boundary.
class DdsError : public std::runtime_error {
 public:
  DdsError(const std::string& what, dds_return_t code);
  dds_return_t code() const { return code_; }

 private:
  dds_return_t code_;
};

// Throws DdsError naming `what` when `result` is a DDS error code; returns it otherwise.
dds_entity_t check_dds(dds_entity_t result, const std::string& what);

// Owns one DDS entity (participant, topic, reader, writer) and deletes it, with its children.
class Entity {
 public:
  Entity() = default;
  explicit Entity(dds_entity_t handle) : handle_(handle) {}
  ~Entity() { reset(); }
  Entity(const Entity&) = delete;
  Entity& operator=(const Entity&) = delete;
  Entity(Entity&& other) noexcept : handle_(std::exchange(other.handle_, 0)) {}
  Entity& operator=(Entity&& other) noexcept {
    if (this != &other) {
      reset();
      handle_ = std::exchange(other.handle_, 0);
    }
    return *this;
  }
  dds_entity_t get() const { return handle_; }
  explicit operator bool() const { return handle_ > 0; }
  void reset();

 private:
  dds_entity_t handle_ = 0;
};

// A participant on `domain`. Which network it uses comes from CYCLONEDDS_URI: on these machines
// that is always configs/dds/loopback.xml (see docs/protocol.md).
Entity make_participant(dds_domainid_t domain);

// featureslam's kinds of delivery (docs/protocol.md): reliable with the last 64 samples per
// instance (session control, requests, result readers); stream: reliable with the last 1024
// samples per instance (pose readers: one instance per session, so a burst of poses is not
// overwritten before it is taken); best effort (status); or durable: reliable,
// transient-local, the last sample per instance, so that a reader that joins later still gets
// the current state (the map directory); or newest: reliable, the last sample per instance only,
// a newer one replacing any not yet acknowledged (views: a slow reader gets the latest, never a
// backlog, and never holds the writer back). Frames use a bounded writer and reader, the
// server's poses and results a bounded writer (below): a keep-last writer keeps the last samples
// of every instance it wrote after they are acknowledged, for its life.
enum class Delivery { reliable, stream, best_effort, durable, newest };

// Topic <prefix>/<name> of type `desc` (every topic is created with reliable QoS; readers and
// writers choose their own).
Entity make_topic(const Entity& participant, const dds_topic_descriptor_t* desc,
                  const std::string& prefix, const char* name);
Entity make_reader(const Entity& participant, const Entity& topic, Delivery delivery);
// A reliable reader that holds at most `max_samples` samples not taken yet (DDS resource limits):
// past it, the protocol holds writers back instead of the reader's memory growing with a
// writer that outpaces it.
Entity make_bounded_reader(const Entity& participant, const Entity& topic, std::int32_t max_samples);
// A reliable writer that holds at most `max_samples` samples not acknowledged by every reader yet:
// a write past it waits up to the reliability's blocking time (1 s), then fails with
// DDS_RETCODE_TIMEOUT, so a publisher faster than its readers cannot queue without bound.
Entity make_bounded_writer(const Entity& participant, const Entity& topic, std::int32_t max_samples);
Entity make_writer(const Entity& participant, const Entity& topic, Delivery delivery);
// A waitset woken when any of `readers` has data.
Entity make_waitset(const Entity& participant, std::initializer_list<const Entity*> readers);

// Topic name with the deployment's prefix, e.g. topic_name("test42", "poses") -> "test42/poses".
// Tests use their own prefix so that parallel runs never see each other.
std::string topic_name(const std::string& prefix, const std::string& topic);

// Takes every sample `reader` holds now, in batches, and calls fn(const T&) on each valid one;
// returns how many it handled. T is the reader's generated C type.
template <typename T, typename Fn>
int take_each(dds_entity_t reader, Fn&& fn) {
  constexpr int kBatch = 16;
  int handled = 0;
  for (;;) {
    void* samples[kBatch] = {nullptr};
    dds_sample_info_t info[kBatch];
    const int32_t n = dds_take(reader, samples, info, kBatch, kBatch);
    if (n <= 0) return handled;
    for (int32_t i = 0; i < n; ++i) {
      if (!info[i].valid_data) continue;
      fn(*static_cast<const T*>(samples[i]));
      ++handled;
    }
    dds_return_loan(reader, samples, n);
  }
}

}  // namespace fslam::client
