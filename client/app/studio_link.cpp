// StudioLink: connect on a thread, stream into the GPU replica, reconnect with backoff (see
// studio_link.hpp).
#include "studio_link.hpp"

#include <algorithm>

#include "deepcanvas/base/log.hpp"

namespace deepcanvas::client_app {
namespace {

constexpr std::chrono::milliseconds kFirstBackoff{500};
constexpr std::chrono::milliseconds kMaxBackoff{10000};

// Refusals that another attempt cannot change.
bool permanent(Errc code) {
  return code == Errc::unauthorized || code == Errc::not_found || code == Errc::unsupported ||
         code == Errc::out_of_memory || code == Errc::limit_exceeded;
}

}  // namespace

StudioLink::Live::~Live() {
  // The epoch listener feeds the replica: remove it before the replica goes; the loop before
  // the replica it renders.
  if (client) client->set_epoch_listener({});
  loop.reset();
  replica.reset();
  if (client) client->close();
}

StudioLink::StudioLink(const client_gpu::Context& ctx, client_core::ClientOptions options)
    : ctx_(ctx), options_(std::move(options)) {
  start_attempt();
}

StudioLink::~StudioLink() {
  live_.reset();
  if (attempt_.valid()) attempt_.wait();  // bounded by the connect timeout
}

void StudioLink::start_attempt() {
  state_ = State::connecting;
  ++attempts_;
  // The attempt's thread gets its own copy: set_join_camera may change options_ meanwhile.
  auto attempt = [this, options = options_]() -> Result<std::unique_ptr<Live>> {
    auto live = std::make_unique<Live>();
    auto client = client_core::Client::connect(options);
    if (!client) return std::move(client).error();
    live->client = std::move(*client);
    auto replica = client_gpu::StreamingReplica::create(
        ctx_, client_gpu::replica_config_for(live->client->welcome()));
    if (!replica) {
      return Error{Errc::out_of_memory,
                   "this device cannot hold the canvas: " + replica.error().message};
    }
    live->replica = std::move(*replica);
    client_gpu::stream_client_into(*live->client, *live->replica);
    client_gpu::RenderLoopOptions lo;
    lo.render.background = {0.05, 0.06, 0.08};
    auto loop = client_gpu::RenderLoop::create(*live->replica, lo);
    if (!loop) return std::move(loop).error();
    live->loop = std::move(*loop);
    return live;
  };
  attempt_ = std::async(std::launch::async, std::move(attempt));
}

void StudioLink::hold_last_frame() {
  if (!live_ || !live_->loop) return;
  const client_gpu::Buffer& out = live_->loop->output();
  if (out.handle() == VK_NULL_HANDLE) return;  // nothing was rendered
  auto held = client_gpu::Buffer::create(
      ctx_, out.size(), VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT,
      client_gpu::MemoryUse::device_local);
  if (!held) {
    held_frame_ = {};
    return;
  }
  // Under the replica's GPU lock, as the render loop submits: its upload thread may still be
  // submitting.
  auto copied = live_->replica->with_gpu([&](const client_gpu::ResidentState&) {
    return ctx_.submit_once(ctx_.compute_queue(), [&](VkCommandBuffer cb) {
      client_gpu::buffer_barrier(cb, out, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                                 VK_ACCESS_SHADER_WRITE_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT,
                                 VK_ACCESS_TRANSFER_READ_BIT);
      const VkBufferCopy region{0, 0, out.size()};
      vkCmdCopyBuffer(cb, out.handle(), held->handle(), 1, &region);
      // present() reads it as it reads the ray caster's output (after a compute-stage barrier).
      client_gpu::buffer_barrier(
          cb, *held, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
          VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT,
          VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_TRANSFER_READ_BIT);
    });
  });
  held_frame_ = copied ? std::move(*held) : client_gpu::Buffer{};
}

void StudioLink::drop(std::string reason, bool permanent_failure,
                      const std::function<void()>& before_release) {
  // The next connection goes on with the handles after this one's: the server remembers the
  // client id's handles (and, with --data, across its restart) and would answer a handle used
  // again with the earlier stroke's ack instead of painting the new one.
  if (live_ && live_->client) options_.first_handle = live_->client->next_handle();
  if (live_ && before_release) before_release();
  hold_last_frame();
  live_.reset();
  reason_ = std::move(reason);
  if (permanent_failure) {
    state_ = State::failed;
    return;
  }
  state_ = State::waiting;
  retry_at_ = Clock::now() + backoff_;
  backoff_ = std::min(backoff_ * 2, kMaxBackoff);
}

void StudioLink::update(Clock::time_point now, const std::function<void()>& before_release) {
  switch (state_) {
    case State::connecting: {
      if (attempt_.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return;
      auto r = attempt_.get();
      if (!r) {
        const bool perm = permanent(r.error().code);
        base::log_event(
            base::LogLevel::warn, "studio_connect_failed",
            {{"url", options_.url}, {"canvas", options_.canvas}, {"error", r.error().message}});
        drop(r.error().message, perm);
        return;
      }
      live_ = std::move(*r);
      state_ = State::live;
      ++connections_;
      reason_.clear();
      backoff_ = kFirstBackoff;
      return;
    }
    case State::live:
      if (live_->client->is_open() && live_->replica->status()) return;
      if (auto s = live_->replica->status(); !s) {
        drop("the GPU replica failed: " + s.error().message, true, before_release);
        return;
      }
      drop("the server closed the connection (code " + std::to_string(live_->client->close_code()) +
               ")",
           false, before_release);
      base::log_event(base::LogLevel::warn, "studio_disconnected", {{"reason", reason_}});
      return;
    case State::waiting:
      if (now >= retry_at_) start_attempt();
      return;
    case State::failed:
      return;
  }
}

void StudioLink::retry_now() {
  if (state_ == State::waiting || state_ == State::failed) {
    backoff_ = kFirstBackoff;
    start_attempt();
  }
}

double StudioLink::retry_in_s(Clock::time_point now) const {
  if (state_ != State::waiting) return 0;
  return std::max(0.0, std::chrono::duration<double>(retry_at_ - now).count());
}

}  // namespace deepcanvas::client_app
