// Client: Boost.Beast WebSocket client with one I/O thread (see client.hpp for the contract):
// connecting (the upgrade, hello and welcome, the I/O thread) and closing. The connection's
// state and handlers are client_impl.hpp; the requests and waits are client_requests.cpp.
#include <algorithm>

#include "client_impl.hpp"

namespace deepcanvas::client_core {

Result<std::unique_ptr<Client>> Client::connect(const ClientOptions& options) {
  auto url = parse_url(options.url);
  if (!url) return std::move(url).error();
  std::unique_ptr<net::ssl::context> tls;
  if (url->tls) {
    auto t = make_tls_context(options.ca_file);
    if (!t) return std::move(t).error();
    tls = std::move(*t);
  }
  std::unique_ptr<Client> client(new Client());
  client->impl_ = std::make_shared<Impl>(std::move(tls));
  Impl& m = *client->impl_;
  m.keep_replica = options.keep_replica;
  m.next_handle = std::max<std::uint64_t>(1, options.first_handle);
  m.progressive_join = options.progressive_join;
  m.progressive_first = options.progressive_first;
  m.block_frames = options.block_frames;
  beast::error_code ec;
  // Connect, handshake, hello and welcome run synchronously before the I/O thread exists.
  tcp::resolver resolver(m.ioc);
  const auto results = resolver.resolve(url->host, url->port, ec);
  if (ec) return make_error(Errc::io_error, "cannot resolve " + url->host + ": " + ec.message());
  m.tcp().expires_after(options.connect_timeout);
  if (options.receive_buffer_bytes > 0) {
    // The option must be set before connecting so that the TCP window is sized by it.
    auto& sock = m.tcp().socket();
    ec = net::error::host_not_found;
    for (const auto& entry : results) {
      beast::error_code e2;
      sock.close(e2);
      sock.open(entry.endpoint().protocol(), e2);
      if (e2) continue;
      sock.set_option(net::socket_base::receive_buffer_size(options.receive_buffer_bytes), e2);
      sock.connect(entry.endpoint(), ec);
      if (!ec) break;
    }
  } else {
    m.tcp().connect(results, ec);
  }
  if (ec)
    return make_error(Errc::io_error, "cannot connect to " + options.url + ": " + ec.message());
  m.tcp().socket().set_option(tcp::no_delay(true), ec);
  if (auto* w = std::get_if<TlsWs>(&m.ws)) {
    if (auto r = tls_handshake(w->next_layer(), *url, options.ca_file); !r) return r.error();
  }
  m.with_ws([&](auto& w) { w.handshake(url->host + ":" + url->port, url->target, ec); });
  if (ec) return make_error(Errc::io_error, "WebSocket handshake failed: " + ec.message());
  m.with_ws([](auto& w) { w.read_message_max(64u << 20); });
  protocol::Hello hello;
  hello.role = options.role;
  hello.token = options.token;
  hello.canvas = options.canvas;
  hello.client_name = options.client_name;
  hello.client_id = options.client_id;
  hello.delta_frames = options.delta_frames;
  hello.frame_bundles = options.frame_bundles;
  hello.block_frames = options.block_frames;
  hello.batch_interval_ms = options.batch_interval_ms;
  hello.camera = options.camera;
  m.with_ws([&](auto& w) {
    w.text(true);
    w.write(net::buffer(protocol::encode_message(hello)), ec);
  });
  if (ec) return make_error(Errc::io_error, "cannot send hello: " + ec.message());
  m.with_ws([&](auto& w) { w.read(m.rbuf, ec); });
  if (ec) return make_error(Errc::io_error, "no welcome: " + ec.message());
  const auto data = m.rbuf.cdata();
  auto reply = protocol::decode_message(
      std::string_view(static_cast<const char*>(data.data()), data.size()));
  m.rbuf.consume(m.rbuf.size());
  if (!reply) return make_error(Errc::malformed, "bad welcome: " + reply.error().message);
  if (auto* e = std::get_if<protocol::ErrorMessage>(&*reply))
    return make_error(e->code, e->message);
  auto* w = std::get_if<protocol::Welcome>(&*reply);
  if (!w)
    return make_error(Errc::malformed,
                      "expected welcome, got " + std::string(protocol::message_type(*reply)));
  if (w->pool_layout.id != protocol::kPoolLayoutId ||
      w->pool_layout.version != protocol::kPoolLayoutVersion)
    return make_error(Errc::unsupported, "unknown pool layout " + w->pool_layout.id);
  m.welcome = *w;
  m.replica = std::make_unique<Replica>(
      ReplicaGeometry{w->geometry.roots_per_axis, w->geometry.edge_m, w->block_cells});
  m.tcp().expires_never();
  m.with_ws([](auto& stream) {
    stream.set_option(websocket::stream_base::timeout::suggested(beast::role_type::client));
  });
  auto impl = client->impl_;
  net::post(m.ioc, [impl] { impl->start_reading(); });
  m.io_thread = std::thread([impl] {
    base::set_thread_name("dc-client-io");
    auto guard = net::make_work_guard(impl->ioc);
    impl->ioc.run();
  });
  return client;
}

Client::~Client() {
  close();
}

void Client::close() {
  if (!impl_ || !impl_->io_thread.joinable()) return;
  auto impl = impl_;
  net::post(impl->ioc, [impl] {
    bool was_open;
    {
      std::lock_guard lock(impl->mutex);
      was_open = impl->open;
    }
    if (!was_open) return impl->ioc.stop();
    if (impl->closing) return;  // a protocol failure is closing it: ended() wakes the wait below
    impl->closing = true;
    impl->with_ws([&](auto& w) {
      w.async_close(websocket::close_code::normal, [impl](beast::error_code) {
        {
          std::lock_guard lock(impl->mutex);
          impl->open = false;
        }
        impl->cv.notify_all();
        impl->ioc.stop();
      });
    });
  });
  // A peer that never answers the close is cut off by the suggested timeout; bound it here too.
  {
    std::unique_lock lock(impl->mutex);
    impl->cv.wait_for(lock, std::chrono::seconds(5), [&] { return !impl->open; });
  }
  impl->ioc.stop();
  impl->io_thread.join();
  // Operations still pending in the io_context hold shared_ptrs to impl (impl owns the
  // io_context: a cycle). Close the socket so they complete with an error, and run them out.
  beast::error_code ignored;
  impl->tcp().socket().close(ignored);
  impl->ioc.restart();
  impl->ioc.run_for(std::chrono::seconds(2));
}

}  // namespace deepcanvas::client_core
