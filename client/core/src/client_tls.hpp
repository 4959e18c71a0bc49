// Connecting: the ws:// / wss:// URL and the TLS context and handshake of a wss:// connection.
// Private to client_core (client.cpp).
#pragma once

#include <boost/asio/ssl.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/ssl.hpp>
#include <memory>
#include <string>

#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_core::detail {

struct ParsedUrl {
  std::string host, port, target;
  bool tls = false;
};

// ws[s]://HOST:PORT[/TARGET] (an IPv6 host in brackets); invalid_argument otherwise.
Result<ParsedUrl> parse_url(const std::string& url);

// The client TLS context: TLS 1.2 or later, peer verification against `ca_file` (PEM) or the
// system's default store.
Result<std::unique_ptr<boost::asio::ssl::context>> make_tls_context(const std::string& ca_file);

// The TLS handshake of a wss:// connection: SNI (for a host name; RFC 6066 forbids IP
// literals there), the certificate chain and the host name (or IP) checked. The error says
// why OpenSSL refused the certificate when it did.
Result<void> tls_handshake(boost::beast::ssl_stream<boost::beast::tcp_stream>& stream,
                           const ParsedUrl& url, const std::string& ca_file);

}  // namespace deepcanvas::client_core::detail
