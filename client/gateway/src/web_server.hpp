// HTTP + WebSocket for fslam-gateway on Boost.Beast (docs/viewer.md): serves the bundled page
// from memory and carries the gateway's messages to every connected browser. One I/O thread;
// other threads hand it messages through ViewerHub.
#pragma once

#include <memory>
#include <string>

#include "gateway.hpp"
#include "options.hpp"

namespace fslam::client::gateway {

class WebServer : public ViewerHub {
 public:
  WebServer(const GatewayOptions& options, Gateway* gateway);
  ~WebServer() override;
  // Reads the page's files and binds the address. False with `why` (no page, address in use).
  bool open(std::string* why);
  // The port bound (after open).
  unsigned short port() const;
  // Serves until stop() (from any thread, e.g. a signal watcher).
  void run();
  void stop();
  void broadcast(OutgoingPtr message) override;
  void send(std::uint64_t viewer, OutgoingPtr message) override;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace fslam::client::gateway
