#include "client_tls.hpp"

#include <openssl/err.h>
#include <openssl/ssl.h>

#include <boost/asio/ip/address.hpp>

namespace deepcanvas::client_core::detail {

namespace beast = boost::beast;
namespace net = boost::asio;

Result<ParsedUrl> parse_url(const std::string& url) {
  ParsedUrl p;
  std::size_t scheme_size = 0;
  if (url.rfind("ws://", 0) == 0) {
    scheme_size = 5;
  } else if (url.rfind("wss://", 0) == 0) {
    scheme_size = 6;
    p.tls = true;
  } else {
    return make_error(Errc::invalid_argument,
                      "url must start with ws:// or wss:// (got '" + url + "')");
  }
  std::string rest = url.substr(scheme_size);
  const auto slash = rest.find('/');
  p.target = slash == std::string::npos ? "/" : rest.substr(slash);
  std::string hostport = rest.substr(0, slash);
  const auto colon = hostport.rfind(':');
  if (colon == std::string::npos || colon + 1 == hostport.size())
    return make_error(Errc::invalid_argument, "url needs HOST:PORT (got '" + url + "')");
  p.host = hostport.substr(0, colon);
  p.port = hostport.substr(colon + 1);
  if (p.host.size() > 2 && p.host.front() == '[') p.host = p.host.substr(1, p.host.size() - 2);
  return p;
}

Result<std::unique_ptr<net::ssl::context>> make_tls_context(const std::string& ca_file) {
  auto ctx = std::make_unique<net::ssl::context>(net::ssl::context::tls_client);
  beast::error_code ec;
  ctx->set_options(net::ssl::context::default_workarounds | net::ssl::context::no_sslv2 |
                       net::ssl::context::no_sslv3 | net::ssl::context::no_tlsv1 |
                       net::ssl::context::no_tlsv1_1,
                   ec);
  if (ec) return make_error(Errc::internal, "cannot set TLS options: " + ec.message());
  if (!ca_file.empty()) {
    ctx->load_verify_file(ca_file, ec);
    if (ec)
      return make_error(Errc::invalid_argument,
                        "cannot load CA file '" + ca_file + "': " + ec.message());
  } else {
    ctx->set_default_verify_paths(ec);
    if (ec) return make_error(Errc::io_error, "cannot load the system CA store: " + ec.message());
  }
  ctx->set_verify_mode(net::ssl::verify_peer);
  return ctx;
}

Result<void> tls_handshake(beast::ssl_stream<beast::tcp_stream>& stream, const ParsedUrl& url,
                           const std::string& ca_file) {
  beast::error_code ec;
  net::ip::make_address(url.host, ec);
  if (ec && !SSL_set_tlsext_host_name(stream.native_handle(), url.host.c_str()))
    return make_error(Errc::invalid_argument, "bad TLS server name '" + url.host + "'");
  stream.set_verify_callback(net::ssl::host_name_verification(url.host));
  ec = {};
  stream.handshake(net::ssl::stream_base::client, ec);
  if (!ec) return {};
  std::string why = ec.message();
  if (const long v = SSL_get_verify_result(stream.native_handle()); v != X509_V_OK)
    why = std::string("certificate not trusted: ") + X509_verify_cert_error_string(v);
  else if (ec.category() == net::error::get_ssl_category() &&
           ERR_GET_REASON(ec.value()) == SSL_R_CERTIFICATE_VERIFY_FAILED)
    why = "certificate not trusted: it does not name " + url.host;
  return make_error(Errc::io_error,
                    "TLS handshake with " + url.host + ":" + url.port + " failed: " + why +
                        (ca_file.empty() ? " (checked against the system CA store)"
                                         : " (checked against CA file '" + ca_file + "')"));
}


}  // namespace deepcanvas::client_core::detail
