#include "web_server.hpp"

#include <algorithm>
#include <deque>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>

#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>

namespace fslam::client::gateway {
namespace {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;

constexpr std::size_t kMaxViewerMessage = 64 * 1024;  // a browser's request is small JSON
constexpr std::size_t kMaxQueuedPerViewer = 4096;     // beyond this a viewer is too slow: closed
constexpr const char* kCookie = "fslam_token";

struct StaticFile {
  std::string body, mime;
};

std::string mime_of(const std::filesystem::path& p) {
  const std::string e = p.extension().string();
  if (e == ".html") return "text/html; charset=utf-8";
  if (e == ".js" || e == ".mjs") return "text/javascript; charset=utf-8";
  if (e == ".css") return "text/css; charset=utf-8";
  if (e == ".png") return "image/png";
  if (e == ".svg") return "image/svg+xml";
  if (e == ".json" || e == ".map") return "application/json";
  if (e == ".wasm") return "application/wasm";
  return "";
}

// Constant time in the length of `expected`: a token is not found out byte by byte.
bool same_secret(const std::string& given, const std::string& expected) {
  unsigned diff = given.size() == expected.size() ? 0u : 1u;
  for (std::size_t i = 0; i < expected.size(); ++i) {
    diff |= static_cast<unsigned>(expected[i]) ^ static_cast<unsigned>(i < given.size() ? given[i] : 0);
  }
  return diff == 0;
}

// The value of `key` in a query string or a cookie header ("a=1&b=2", "a=1; b=2").
std::string find_value(const std::string& text, const std::string& key, char separator) {
  std::size_t pos = 0;
  while (pos <= text.size()) {
    std::size_t end = text.find(separator, pos);
    if (end == std::string::npos) end = text.size();
    std::string item = text.substr(pos, end - pos);
    item.erase(0, item.find_first_not_of(' '));
    if (item.rfind(key + "=", 0) == 0) return item.substr(key.size() + 1);
    pos = end + 1;
  }
  return "";
}

// The host name of a Host header: "127.0.0.1:8090" -> "127.0.0.1", "[::1]:8090" -> "[::1]".
std::string host_name(const std::string& host) {
  if (!host.empty() && host[0] == '[') return host.substr(0, host.find(']') + 1);
  return host.substr(0, host.find(':'));
}

}  // namespace

struct WebServer::Impl {
  class Viewer;
  class HttpConnection;

  GatewayOptions options;
  Gateway* gateway;
  net::io_context io{1};
  tcp::acceptor acceptor{io};
  std::map<std::string, StaticFile> files;  // URL path -> file, read once at start
  std::map<std::uint64_t, std::weak_ptr<Viewer>> viewers;  // I/O thread only
  std::uint64_t next_viewer = 1;

  Impl(const GatewayOptions& o, Gateway* g) : options(o), gateway(g) {}
  void accept();
  // Loopback without a token: only loopback host names (a page elsewhere that resolves its own
  // name to 127.0.0.1 must not reach us: DNS rebinding). With a token: the token, from the URL
  // or the cookie the page got with it.
  bool authorised(const http::request<http::string_body>& req, bool* from_url) const;
};

class WebServer::Impl::Viewer : public std::enable_shared_from_this<Viewer> {
 public:
  Viewer(Impl* server, tcp::socket socket, std::uint64_t id)
      : server_(server), ws_(std::move(socket)), id_(id) {}
  void start(http::request<http::string_body> req) {
    ws_.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    ws_.read_message_max(kMaxViewerMessage);
    ws_.async_accept(req, [self = shared_from_this()](beast::error_code ec) {
      if (ec) return;
      self->server_->viewers[self->id_] = self;
      for (OutgoingPtr& m : self->server_->gateway->welcome(self->id_)) self->push(std::move(m));
      self->read();
    });
  }
  // I/O thread.
  void push(OutgoingPtr message) {
    if (closed_) return;
    if (!message->replaceable.empty()) {
      // A newer version of a map replaces one still waiting (not the one being written).
      for (std::size_t i = writing_ ? 1 : 0; i < queue_.size(); ++i) {
        if (queue_[i]->replaceable == message->replaceable) {
          queue_[i] = std::move(message);
          return;
        }
      }
    }
    if (queue_.size() >= kMaxQueuedPerViewer) return close();
    queue_.push_back(std::move(message));
    if (!writing_) write();
  }

 private:
  void read() {
    ws_.async_read(buffer_, [self = shared_from_this()](beast::error_code ec, std::size_t) {
      if (ec) return self->close();
      if (self->ws_.got_text()) {
        self->server_->gateway->on_message(self->id_, beast::buffers_to_string(self->buffer_.data()));
      }
      self->buffer_.consume(self->buffer_.size());
      self->read();
    });
  }
  void write() {
    writing_ = true;
    const OutgoingPtr& m = queue_.front();
    ws_.binary(m->binary);
    ws_.async_write(net::buffer(m->data), [self = shared_from_this()](beast::error_code ec, std::size_t) {
      self->writing_ = false;
      if (ec) return self->close();
      self->queue_.pop_front();
      if (!self->queue_.empty()) self->write();
    });
  }
  void close() {
    if (closed_) return;
    closed_ = true;
    queue_.clear();
    server_->viewers.erase(id_);
    server_->gateway->on_viewer_closed(id_);
    beast::error_code ignored;
    beast::get_lowest_layer(ws_).socket().close(ignored);
  }

  Impl* server_;
  websocket::stream<beast::tcp_stream> ws_;
  std::uint64_t id_;
  beast::flat_buffer buffer_;
  std::deque<OutgoingPtr> queue_;
  bool writing_ = false, closed_ = false;
};

class WebServer::Impl::HttpConnection : public std::enable_shared_from_this<HttpConnection> {
 public:
  HttpConnection(Impl* server, tcp::socket socket) : server_(server), stream_(std::move(socket)) {}
  void read() {
    parser_.emplace();
    parser_->header_limit(8 * 1024);
    parser_->body_limit(4 * 1024);  // GETs only: no bodies worth reading
    stream_.expires_after(std::chrono::seconds(30));
    http::async_read(stream_, buffer_, *parser_, [self = shared_from_this()](beast::error_code ec, std::size_t) {
      if (ec) return self->shutdown();
      self->handle(self->parser_->release());
    });
  }

 private:
  void handle(http::request<http::string_body> req) {
    bool from_url = false;
    if (!server_->authorised(req, &from_url)) {
      return reply(req, http::status::forbidden, "text/plain",
                   server_->options.token.empty() ? "forbidden: use a loopback address (127.0.0.1 or localhost)\n"
                                                  : "forbidden: open the URL with ?token=<the gateway's token>\n");
    }
    if (websocket::is_upgrade(req)) {
      // Same origin only: another site's page in this browser cannot drive the viewer.
      const std::string origin(req[http::field::origin]);
      const std::string host(req[http::field::host]);
      if (!origin.empty() && origin != "http://" + host) {
        return reply(req, http::status::forbidden, "text/plain", "forbidden: cross-origin WebSocket\n");
      }
      if (static_cast<int>(server_->viewers.size()) >= server_->options.max_viewers) {
        return reply(req, http::status::service_unavailable, "text/plain", "too many viewers connected\n");
      }
      stream_.expires_never();
      auto viewer = std::make_shared<Viewer>(server_, stream_.release_socket(), server_->next_viewer++);
      viewer->start(std::move(req));
      return;
    }
    if (req.method() != http::verb::get && req.method() != http::verb::head) {
      return reply(req, http::status::method_not_allowed, "text/plain", "GET only\n");
    }
    std::string path(req.target().substr(0, req.target().find('?')));
    if (path == "/") path = "/index.html";
    const auto it = server_->files.find(path);
    if (it == server_->files.end()) return reply(req, http::status::not_found, "text/plain", "not found\n");
    std::string cookie;
    if (from_url) {
      cookie = std::string(kCookie) + "=" + server_->options.token + "; HttpOnly; SameSite=Strict; Path=/";
    }
    reply(req, http::status::ok, it->second.mime, it->second.body, cookie);
  }
  void reply(const http::request<http::string_body>& req, http::status status, const std::string& mime,
             const std::string& body, const std::string& cookie = "") {
    auto res = std::make_shared<http::response<http::string_body>>(status, req.version());
    res->set(http::field::server, "fslam-gateway");
    res->set(http::field::content_type, mime);
    res->set(http::field::cache_control, "no-store");
    res->set("X-Content-Type-Options", "nosniff");
    res->set("X-Frame-Options", "DENY");
    res->set("Referrer-Policy", "no-referrer");
    if (!cookie.empty()) res->set(http::field::set_cookie, cookie);
    res->keep_alive(req.keep_alive() && status == http::status::ok);
    if (req.method() != http::verb::head) res->body() = body;
    res->prepare_payload();
    http::async_write(stream_, *res, [self = shared_from_this(), res](beast::error_code ec, std::size_t) {
      if (ec || !res->keep_alive()) return self->shutdown();
      self->read();
    });
  }
  void shutdown() {
    beast::error_code ignored;
    stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
  }

  Impl* server_;
  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
};

bool WebServer::Impl::authorised(const http::request<http::string_body>& req, bool* from_url) const {
  *from_url = false;
  if (options.token.empty()) {
    const std::string host = host_name(std::string(req[http::field::host]));
    return is_loopback(host);
  }
  const std::string target(req.target());
  const auto q = target.find('?');
  const std::string in_url = q == std::string::npos ? "" : find_value(target.substr(q + 1), "token", '&');
  if (!in_url.empty() && same_secret(in_url, options.token)) {
    *from_url = true;
    return true;
  }
  return same_secret(find_value(std::string(req[http::field::cookie]), kCookie, ';'), options.token);
}

void WebServer::Impl::accept() {
  acceptor.async_accept([this](beast::error_code ec, tcp::socket socket) {
    if (!acceptor.is_open()) return;
    if (!ec) std::make_shared<HttpConnection>(this, std::move(socket))->read();
    accept();
  });
}

WebServer::WebServer(const GatewayOptions& options, Gateway* gateway)
    : impl_(std::make_unique<Impl>(options, gateway)) {}

WebServer::~WebServer() = default;

bool WebServer::open(std::string* why) {
  namespace fs = std::filesystem;
  const fs::path root = impl_->options.web_dir;
  std::error_code ec;
  if (!fs::is_regular_file(root / "index.html", ec)) {
    if (why) *why = "no viewer page at " + (root / "index.html").string() +
                    " (bash deploy/setup.sh bundles it; or pass --web DIR)";
    return false;
  }
  // Every file is read now: requests can only name what was there at start, nothing else on
  // this machine (no path is ever joined from a request).
  for (auto it = fs::recursive_directory_iterator(root, ec); it != fs::recursive_directory_iterator(); ++it) {
    if (it.depth() > 2 || !it->is_regular_file()) continue;
    const std::string mime = mime_of(it->path());
    if (mime.empty()) continue;
    std::ifstream in(it->path(), std::ios::binary);
    std::stringstream body;
    body << in.rdbuf();
    impl_->files["/" + fs::relative(it->path(), root).generic_string()] = {body.str(), mime};
  }
  try {
    const tcp::endpoint endpoint(net::ip::make_address(impl_->options.address == "localhost" ? "127.0.0.1"
                                                                                             : impl_->options.address),
                                 impl_->options.port);
    impl_->acceptor.open(endpoint.protocol());
    impl_->acceptor.set_option(net::socket_base::reuse_address(true));
    impl_->acceptor.bind(endpoint);
    impl_->acceptor.listen(net::socket_base::max_listen_connections);
  } catch (const std::exception& e) {
    if (why) *why = "cannot listen on " + impl_->options.address + ":" + std::to_string(impl_->options.port) +
                    ": " + e.what();
    return false;
  }
  impl_->accept();
  return true;
}

unsigned short WebServer::port() const { return impl_->acceptor.local_endpoint().port(); }

void WebServer::run() {
  net::signal_set signals(impl_->io, SIGINT, SIGTERM);
  signals.async_wait([this](beast::error_code, int) { stop(); });
  impl_->io.run();
}

void WebServer::stop() {
  net::post(impl_->io, [this] {
    beast::error_code ignored;
    impl_->acceptor.close(ignored);
    impl_->io.stop();
  });
}

void WebServer::broadcast(OutgoingPtr message) {
  net::post(impl_->io, [this, message = std::move(message)] {
    // push() may close a viewer, which leaves the map: go over a copy.
    std::vector<std::shared_ptr<Impl::Viewer>> all;
    for (auto& [id, weak] : impl_->viewers) {
      if (auto viewer = weak.lock()) all.push_back(std::move(viewer));
    }
    for (auto& viewer : all) viewer->push(message);
  });
}

void WebServer::send(std::uint64_t viewer, OutgoingPtr message) {
  net::post(impl_->io, [this, viewer, message = std::move(message)] {
    const auto it = impl_->viewers.find(viewer);
    if (it == impl_->viewers.end()) return;
    if (auto v = it->second.lock()) v->push(message);
  });
}

}  // namespace fslam::client::gateway
