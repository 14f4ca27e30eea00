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

std::string topic_name(const std::string& prefix, const std::string& topic) {
  return prefix.empty() ? "fslam/" + topic : prefix + "/" + topic;
}

}  // namespace fslam::client
