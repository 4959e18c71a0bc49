// StudioLink: the studio window's connection to its canvas, kept alive across server restarts.
//
// A link is a client_core::Client (a painter, or a viewer with --viewer) streaming into a
// StreamingReplica on the window's device, and a RenderLoop over it that the frame loop drives
// frame by frame. Connecting blocks (name lookup, TLS, the hello and the welcome), so it runs on a
// thread of its own; the frame loop only ever polls (update()), so it never waits for the
// network.
//
// States: connecting -> live -> (the connection ends) -> waiting -> connecting ... The wait after
// a lost or failed connection doubles from 0.5 s up to 10 s, and is reset by a live link. A
// refusal that retrying cannot fix (a wrong token, a viewer-only token for a painter, a canvas the
// server does not have, a canvas larger than the device's textures) ends in `failed` with the
// reason; the window shows it and the artist can retry by hand (retry_now()).
//
// Threading: every member function on the frame loop's thread.
#pragma once

#include <chrono>
#include <functional>
#include <future>
#include <memory>
#include <string>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/memory.hpp"
#include "deepcanvas/client_gpu/render_loop.hpp"
#include "deepcanvas/client_gpu/streaming_replica.hpp"

namespace deepcanvas::client_app {

class StudioLink {
 public:
  enum class State { connecting, live, waiting, failed };
  using Clock = std::chrono::steady_clock;

  StudioLink(const client_gpu::Context& ctx, client_core::ClientOptions options);
  ~StudioLink();
  StudioLink(const StudioLink&) = delete;
  StudioLink& operator=(const StudioLink&) = delete;

  // Advances the state machine: takes a finished connection attempt, notices a lost one,
  // starts the next attempt when its wait is over. Never blocks, but for `before_release`:
  // called before a lost connection's render loop (and the output buffer the window may still
  // be presenting from) is destroyed; the window waits for its frame there.
  void update(Clock::time_point now, const std::function<void()>& before_release = {});
  void retry_now();
  // The camera the next connection attempt gives in hello (ClientOptions::camera): after the
  // server went away, the canvas comes back nearest the view first.
  void set_join_camera(const protocol::JoinCamera& camera) { options_.camera = camera; }

  State state() const noexcept { return state_; }
  // Why the last connection ended or failed (empty while none did).
  const std::string& reason() const noexcept { return reason_; }
  // Seconds until the next attempt (waiting only).
  double retry_in_s(Clock::time_point now) const;
  int attempts() const noexcept { return attempts_; }
  // How many connections went live: a new value means a new connection (and client()).
  int connections() const noexcept { return connections_; }

  // live only (null otherwise).
  client_core::Client* client() const noexcept { return live_ ? live_->client.get() : nullptr; }
  client_gpu::StreamingReplica* replica() const noexcept {
    return live_ ? live_->replica.get() : nullptr;
  }
  client_gpu::RenderLoop* loop() const noexcept { return live_ ? live_->loop.get() : nullptr; }
  // The last picture the connection that ended had ray cast (a copy of its RenderLoop::output(),
  // device-local), so the window keeps showing the canvas while it reconnects; null before any
  // connection ended with a picture. Replaced when the next connection ends.
  const client_gpu::Buffer* held_frame() const noexcept {
    return held_frame_.handle() != VK_NULL_HANDLE ? &held_frame_ : nullptr;
  }

 private:
  struct Live {
    std::unique_ptr<client_core::Client> client;
    std::unique_ptr<client_gpu::StreamingReplica> replica;
    std::unique_ptr<client_gpu::RenderLoop> loop;
    ~Live();
  };
  void start_attempt();
  void drop(std::string reason, bool permanent, const std::function<void()>& before_release = {});
  void hold_last_frame();

  const client_gpu::Context& ctx_;
  client_core::ClientOptions options_;
  State state_ = State::connecting;
  std::string reason_;
  std::future<Result<std::unique_ptr<Live>>> attempt_;
  std::unique_ptr<Live> live_;
  client_gpu::Buffer held_frame_;
  Clock::time_point retry_at_{};
  std::chrono::milliseconds backoff_{500};
  int attempts_ = 0;
  int connections_ = 0;
};

}  // namespace deepcanvas::client_app
