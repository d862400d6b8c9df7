#pragma once

// A small HTTP server for stackgen-monitor over GNU libmicrohttpd (Debian's
// libmicrohttpd-dev): its own thread, one handler for every GET.

#include <functional>
#include <memory>
#include <string>

namespace stackgen {

/// What the handler answers.
struct HttpResponse {
  int status = 200;
  std::string content_type = "text/plain; charset=utf-8";
  std::string body;
};

/// Called on the server's thread for each request with its method and path (no query string).
using HttpHandler = std::function<HttpResponse(const std::string& method, const std::string& path)>;

/// Serves `handler` on `bind_address` (an IPv4 address: 127.0.0.1 for this host only, 0.0.0.0
/// for every interface) and `port` (0: one the system picks) from a thread of libmicrohttpd's
/// until destroyed. Methods other than GET and HEAD get 405 without calling the handler.
class HttpServer {
 public:
  /// Throws std::runtime_error naming the address and port when the address is not an IPv4
  /// address or the server cannot listen there (the port in use, say).
  HttpServer(const std::string& bind_address, int port, HttpHandler handler);
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  /// The port it listens on (the one picked, when asked for 0).
  int port() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stackgen
