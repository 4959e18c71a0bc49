// Client's requests (strokes, pick-ups, undo, import, export, playback, stats, presence) and
// the waits for their answers, the epochs and the replica (see client.hpp for the contract).
#include "client_impl.hpp"

namespace deepcanvas::client_core {

const protocol::Welcome& Client::welcome() const noexcept {
  return impl_->welcome;
}

Result<std::uint64_t> Client::send_stroke(const protocol::Stroke& stroke) {
  const std::uint64_t h = impl_->take_handle();
  auto r = impl_->send(protocol::StrokeMessage{h, stroke});
  if (!r) return std::move(r).error();
  return h;
}

std::uint64_t Client::next_handle() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->next_handle;
}

Result<std::uint64_t> Client::begin_stroke(const protocol::Brush& brush,
                                           std::vector<protocol::StrokeSample> samples) {
  const std::uint64_t h = impl_->take_handle();
  auto r = impl_->send(protocol::StrokeBegin{h, brush, std::move(samples)});
  if (!r) return std::move(r).error();
  return h;
}

Result<void> Client::add_samples(std::uint64_t handle,
                                 std::vector<protocol::StrokeSample> samples) {
  return impl_->send(protocol::StrokeSamples{handle, std::move(samples)});
}

Result<void> Client::end_stroke(std::uint64_t handle) {
  return impl_->send(protocol::StrokeEnd{handle});
}

Result<std::uint64_t> Client::request_pick_up(double x, double y, double z) {
  const std::uint64_t id = impl_->take_handle();
  protocol::PickUp p;
  p.request_id = id;
  p.position[0] = x;
  p.position[1] = y;
  p.position[2] = z;
  auto r = impl_->send(p);
  if (!r) return std::move(r).error();
  return id;
}

Result<std::uint64_t> Client::request_undo(bool redo) {
  const std::uint64_t id = impl_->take_handle();
  auto r = redo ? impl_->send(protocol::Redo{id}) : impl_->send(protocol::Undo{id});
  if (!r) return std::move(r).error();
  return id;
}

Result<protocol::UndoReply> Client::wait_for_undo(std::uint64_t request_id,
                                                  std::chrono::milliseconds timeout) {
  return impl_->take_answer(impl_->undos, request_id, timeout, "undo/redo");
}

Result<std::uint64_t> Client::request_import(protocol::Import m) {
  return impl_->send_request(std::move(m));
}

Result<protocol::ImportReply> Client::wait_for_import(std::uint64_t request_id,
                                                      std::chrono::milliseconds timeout) {
  return impl_->take_answer(impl_->imports, request_id, timeout, "import");
}

Result<std::uint64_t> Client::request_export(protocol::ExportRequest m) {
  return impl_->send_request(std::move(m));
}

Result<protocol::ExportReply> Client::wait_for_export(std::uint64_t request_id,
                                                      std::chrono::milliseconds timeout) {
  return impl_->take_answer(impl_->exports, request_id, timeout, "export");
}

Result<std::uint64_t> Client::request_playback_step(protocol::PlaybackStep m) {
  return impl_->send_request(std::move(m));
}

Result<protocol::PlaybackPosition> Client::wait_for_playback(std::uint64_t request_id,
                                                             std::chrono::milliseconds timeout) {
  return impl_->take_answer(impl_->playbacks, request_id, timeout, "playback step");
}

Result<void> Client::request_stats() {
  // Forget any earlier reply before asking, not when waiting: the reply may arrive before
  // wait_for_stats() is called.
  {
    std::lock_guard lock(impl_->mutex);
    impl_->last_stats.reset();
  }
  return impl_->send(protocol::StatsRequest{});
}

Result<void> Client::send_presence(const protocol::Presence& p) {
  // The server's own decoder, with this canvas's bounds: what it would refuse is refused here,
  // with the same message, and not sent.
  std::string text = protocol::encode_message(p);
  if (auto d = protocol::decode_message(text, impl_->decode_options()); !d)
    return make_error(d.error().code, "presence: " + d.error().message);
  {
    std::lock_guard lock(impl_->mutex);
    if (!impl_->open) return make_error(Errc::io_error, "connection closed");
  }
  Impl::Out o;
  o.text = std::move(text);
  impl_->queue(std::move(o));
  return {};
}

Result<void> Client::send_text(std::string text) {
  Impl::Out o;
  o.text = std::move(text);
  impl_->queue(std::move(o));
  return {};
}

Result<void> Client::send_binary(std::vector<std::uint8_t> bytes) {
  Impl::Out o;
  o.binary = std::move(bytes);
  o.is_binary = true;
  impl_->queue(std::move(o));
  return {};
}

Result<std::uint64_t> Client::wait_for_epoch(std::uint64_t epoch,
                                             std::chrono::milliseconds timeout) {
  if (!impl_->block_frames)
    return make_error(Errc::invalid_argument,
                      "this client asked for no block frames: it receives no epochs");
  std::unique_lock lock(impl_->mutex);
  if (!impl_->cv.wait_for(lock, timeout,
                          [&] {
                            return (impl_->stats.epochs > 0 && impl_->applied_epoch >= epoch) ||
                                   !impl_->open;
                          }) ||
      impl_->stats.epochs == 0 || impl_->applied_epoch < epoch)
    return make_error(Errc::io_error, "epoch " + std::to_string(epoch) + " not reached (at " +
                                          std::to_string(impl_->applied_epoch) + ")");
  return impl_->applied_epoch;
}

Result<protocol::Ack> Client::wait_for_ack(std::uint64_t handle,
                                           std::chrono::milliseconds timeout) {
  std::unique_lock lock(impl_->mutex);
  impl_->cv.wait_for(lock, timeout, [&] { return impl_->acks.count(handle) || !impl_->open; });
  auto it = impl_->acks.find(handle);
  if (it == impl_->acks.end())
    return make_error(Errc::io_error, "no ack for stroke handle " + std::to_string(handle));
  return it->second;
}

Result<protocol::PickUpReply> Client::wait_for_pick_up(std::uint64_t request_id,
                                                       std::chrono::milliseconds timeout) {
  std::unique_lock lock(impl_->mutex);
  impl_->cv.wait_for(lock, timeout, [&] { return impl_->picks.count(request_id) || !impl_->open; });
  auto it = impl_->picks.find(request_id);
  if (it == impl_->picks.end())
    return make_error(Errc::io_error, "no pick-up reply for " + std::to_string(request_id));
  return it->second;
}

Result<protocol::Stats> Client::wait_for_stats(std::chrono::milliseconds timeout) {
  std::unique_lock lock(impl_->mutex);
  impl_->cv.wait_for(lock, timeout, [&] { return impl_->last_stats || !impl_->open; });
  if (!impl_->last_stats) return make_error(Errc::io_error, "no stats reply");
  return *impl_->last_stats;
}

std::optional<protocol::ErrorMessage> Client::wait_for_error(std::chrono::milliseconds timeout) {
  std::unique_lock lock(impl_->mutex);
  impl_->cv.wait_for(lock, timeout, [&] { return !impl_->errors.empty() || !impl_->open; });
  if (impl_->errors.empty()) return std::nullopt;
  auto e = std::move(impl_->errors.front());
  impl_->errors.pop_front();
  return e;
}

bool Client::wait_for_close(std::chrono::milliseconds timeout) {
  std::unique_lock lock(impl_->mutex);
  return impl_->cv.wait_for(lock, timeout, [&] { return !impl_->open; });
}

bool Client::is_open() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->open;
}

int Client::close_code() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->close_code;
}

void Client::pause_reading() {
  std::promise<void> done;
  auto f = done.get_future();
  net::post(impl_->ioc, [impl = impl_, &done] {
    impl->paused = true;
    done.set_value();
  });
  f.wait();
}

void Client::resume_reading() {
  net::post(impl_->ioc, [impl = impl_] {
    impl->paused = false;
    impl->start_reading();
  });
}

std::uint64_t Client::applied_epoch() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->applied_epoch;
}

std::uint64_t Client::pool_hash() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->replica ? impl_->replica->pool_hash() : 0;
}

std::uint64_t Client::links_hash() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->replica ? impl_->replica->links_hash() : 0;
}

void Client::with_replica(const std::function<void(const Replica&)>& fn) const {
  std::lock_guard lock(impl_->mutex);
  if (impl_->replica) fn(*impl_->replica);
}

void Client::set_epoch_listener(std::function<void(const EpochCommit&)> fn) {
  std::lock_guard lock(impl_->mutex);
  impl_->epoch_listener = std::move(fn);
  if (impl_->epoch_listener && impl_->replica &&
      (impl_->stats.epochs > 0 || impl_->replica->partial())) {
    const CommittedRange all{0, impl_->replica->high_water_cells()};
    std::vector<std::uint32_t> groups(impl_->replica->high_water_cells() / 8);
    for (std::size_t g = 0; g < groups.size(); ++g) groups[g] = static_cast<std::uint32_t>(g);
    EpochCommit c{impl_->replica->partial() ? impl_->last_frame_epoch : impl_->applied_epoch,
                  *impl_->replica, std::span<const CommittedRange>(&all, 1), groups, true};
    c.partial = impl_->replica->partial();
    impl_->epoch_listener(c);
  }
}

ClientStats Client::stats() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->stats;
}

std::vector<protocol::PresenceUpdate> Client::presence() const {
  std::lock_guard lock(impl_->mutex);
  std::vector<protocol::PresenceUpdate> out;
  out.reserve(impl_->presence.size());
  for (const auto& [artist, u] : impl_->presence) out.push_back(u);
  return out;
}

std::uint64_t Client::presence_updates_received() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->presence_updates;
}

std::optional<Clock::time_point> Client::first_frame_after(std::uint64_t after_epoch) const {
  std::lock_guard lock(impl_->mutex);
  for (const auto& [e, t] : impl_->first_frames)
    if (e > after_epoch) return t;
  return std::nullopt;
}

}  // namespace deepcanvas::client_core
