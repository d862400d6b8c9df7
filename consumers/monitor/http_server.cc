#include "consumers/monitor/http_server.h"

#include <arpa/inet.h>
#include <microhttpd.h>
#include <netinet/in.h>

#include <cstring>
#include <stdexcept>

namespace stackgen {

struct HttpServer::Impl {
  HttpHandler handler;
  MHD_Daemon* daemon = nullptr;
  int port = 0;
};

namespace {

// libmicrohttpd's access handler: every request answered at its first call (no bodies read)
MHD_Result Answer(void* context, MHD_Connection* connection, const char* url, const char* method,
                  const char* /*version*/, const char* /*upload_data*/,
                  size_t* /*upload_data_size*/, void** /*request_context*/) {
  const auto& handler = *static_cast<const HttpHandler*>(context);
  HttpResponse answer;
  const std::string verb = method;
  if (verb != "GET" && verb != "HEAD") {
    answer.status = 405;
    answer.body = "only GET and HEAD\n";
  } else {
    try {
      answer = handler(verb, url);
    } catch (const std::exception& error) {
      answer = HttpResponse{500, "text/plain; charset=utf-8", std::string(error.what()) + "\n"};
    }
  }
  MHD_Response* response = MHD_create_response_from_buffer(
      answer.body.size(), const_cast<char*>(answer.body.data()), MHD_RESPMEM_MUST_COPY);
  if (response == nullptr) return MHD_NO;
  MHD_add_response_header(response, "Content-Type", answer.content_type.c_str());
  MHD_add_response_header(response, "Cache-Control", "no-store");
  const MHD_Result queued =
      MHD_queue_response(connection, static_cast<unsigned int>(answer.status), response);
  MHD_destroy_response(response);
  return queued;
}

}  // namespace

HttpServer::HttpServer(const std::string& bind_address, int port, HttpHandler handler)
    : impl_(std::make_unique<Impl>()) {
  impl_->handler = std::move(handler);
  const std::string where = bind_address + ":" + std::to_string(port);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_port = htons(static_cast<uint16_t>(port));
  if (port < 0 || port > 65535 ||
      inet_pton(AF_INET, bind_address.c_str(), &address.sin_addr) != 1) {
    throw std::runtime_error("cannot serve on " + where + ": not an IPv4 address and port");
  }
  impl_->daemon = MHD_start_daemon(
      MHD_USE_INTERNAL_POLLING_THREAD, static_cast<uint16_t>(port), nullptr, nullptr,
      &Answer, &impl_->handler, MHD_OPTION_SOCK_ADDR,
      reinterpret_cast<sockaddr*>(&address), MHD_OPTION_CONNECTION_TIMEOUT,
      static_cast<unsigned int>(10), MHD_OPTION_END);
  if (impl_->daemon == nullptr) {
    throw std::runtime_error("cannot serve on " + where + ": " + std::strerror(errno) +
                             " (is the port in use?)");
  }
  const MHD_DaemonInfo* info = MHD_get_daemon_info(impl_->daemon, MHD_DAEMON_INFO_BIND_PORT);
  impl_->port = info != nullptr ? info->port : port;
}

HttpServer::~HttpServer() {
  if (impl_->daemon != nullptr) MHD_stop_daemon(impl_->daemon);
}

int HttpServer::port() const { return impl_->port; }

}  // namespace stackgen
