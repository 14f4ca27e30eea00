#include "fslam/client/dds.hpp"

namespace fslam::client {

DdsError::DdsError(const std::string& what, dds_return_t code)
    : std::runtime_error(what + ": " + dds_strretcode(code)), code_(code) {}

dds_entity_t check_dds(dds_entity_t result, const std::string& what) {
  if (result < 0) throw DdsError(what, result);
  return result;
}

void Entity::reset() {
  if (handle_ > 0) dds_delete(handle_);
  handle_ = 0;
}

Entity make_participant(dds_domainid_t domain) {
  return Entity(check_dds(dds_create_participant(domain, nullptr, nullptr),
                          "cannot create a DDS participant on domain " + std::to_string(domain) +
                              " (check CYCLONEDDS_URI)"));
}

namespace {

// A QoS object for `delivery`, deleted when it goes out of scope.
struct Qos {
  dds_qos_t* qos = dds_create_qos();
  explicit Qos(Delivery delivery) {
    if (delivery == Delivery::reliable) {
      dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
      dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 64);
    } else if (delivery == Delivery::stream) {
      dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
      dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 1024);
    } else if (delivery == Delivery::newest) {
      dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
      dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 1);
    } else if (delivery == Delivery::durable) {
      dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
      dds_qset_durability(qos, DDS_DURABILITY_TRANSIENT_LOCAL);
      dds_qset_history(qos, DDS_HISTORY_KEEP_LAST, 1);
    } else {
      dds_qset_reliability(qos, DDS_RELIABILITY_BEST_EFFORT, 0);
    }
  }
  ~Qos() { dds_delete_qos(qos); }
  Qos(const Qos&) = delete;
  Qos& operator=(const Qos&) = delete;
};

}  // namespace

Entity make_topic(const Entity& participant, const dds_topic_descriptor_t* desc,
                  const std::string& prefix, const char* name) {
  const Qos qos(Delivery::reliable);
  return Entity(check_dds(dds_create_topic(participant.get(), desc, topic_name(prefix, name).c_str(),
                                           qos.qos, nullptr),
                          std::string("create topic ") + name));
}

Entity make_reader(const Entity& participant, const Entity& topic, Delivery delivery) {
  const Qos qos(delivery);
  return Entity(check_dds(dds_create_reader(participant.get(), topic.get(), qos.qos, nullptr), "create reader"));
}

Entity make_bounded_reader(const Entity& participant, const Entity& topic, std::int32_t max_samples) {
  const Qos qos(Delivery::reliable);
  dds_qset_history(qos.qos, DDS_HISTORY_KEEP_ALL, 0);
  dds_qset_resource_limits(qos.qos, max_samples, DDS_LENGTH_UNLIMITED, max_samples);
  return Entity(check_dds(dds_create_reader(participant.get(), topic.get(), qos.qos, nullptr), "create reader"));
}

Entity make_bounded_writer(const Entity& participant, const Entity& topic, std::int32_t max_samples) {
  const Qos qos(Delivery::reliable);
  dds_qset_history(qos.qos, DDS_HISTORY_KEEP_ALL, 0);
  dds_qset_resource_limits(qos.qos, max_samples, DDS_LENGTH_UNLIMITED, max_samples);
  return Entity(check_dds(dds_create_writer(participant.get(), topic.get(), qos.qos, nullptr), "create writer"));
}

Entity make_writer(const Entity& participant, const Entity& topic, Delivery delivery) {
  const Qos qos(delivery);
  return Entity(check_dds(dds_create_writer(participant.get(), topic.get(), qos.qos, nullptr), "create writer"));
}

Entity make_waitset(const Entity& participant, std::initializer_list<const Entity*> readers) {
  Entity waitset(check_dds(dds_create_waitset(participant.get()), "create waitset"));
  for (const Entity* reader : readers) {
    check_dds(dds_set_status_mask(reader->get(), DDS_DATA_AVAILABLE_STATUS), "status mask");
    check_dds(dds_waitset_attach(waitset.get(), reader->get(), reader->get()), "attach");
  }
  return waitset;
}

std::string topic_name(const std::string& prefix, const std::string& topic) {
  return prefix.empty() ? "fslam/" + topic : prefix + "/" + topic;
}

}  // namespace fslam::client
