// SessionHandler, presence (PROTOCOL.md 3.9): a painter's presence relayed to the canvas's other
// sessions at most once per kPresenceInterval, and the other artists' presence written to this
// one from its inbox. See session_handler.hpp and presence_relay.hpp.
#include "deepcanvas/server_net/session_handler.hpp"

namespace deepcanvas::server_net {

using server_core::Clock;

void SessionHandler::join_presence(const std::string& client_name) {
  client_name_ = client_name;
  if (!ctx_.presence) return;
  // The wake comes from the publishing session's thread: it posts the pump to this strand.
  presence_inbox_ = ctx_.presence->join(canvas_->name(), id_, [post = post_, this] {
    post([this] { pump_presence(); });
  });
}

void SessionHandler::leave_presence() {
  if (!presence_inbox_) return;
  presence_inbox_.reset();
  presence_held_.reset();
  protocol::PresenceUpdate gone;
  gone.artist = id_;
  gone.name = client_name_;
  gone.gone = true;
  ctx_.presence->leave(canvas_->name(), id_,
                       std::make_shared<const std::string>(protocol::encode_message(gone)));
}

void SessionHandler::on_presence(const protocol::Presence& p) {
  if (role_ != protocol::Role::painter)
    return reply_error(
        make_error(Errc::unauthorized, "viewers may not send presence (only painters have a brush)"),
        {"presence", {}});
  if (!presence_inbox_) return;  // no relay: nobody to tell
  if (presence_timer_armed_) {
    // The interval is running: this one replaces the one held back, and goes out when it ends.
    if (presence_held_) metrics_.presence_held.add();
    presence_held_ = p;
    return;
  }
  const auto now = ctx_.now();
  const auto since = now - presence_last_relayed_;
  if (!presence_relayed_ || since >= kPresenceInterval) return relay_presence(p, now);
  presence_held_ = p;
  presence_timer_armed_ = true;
  out_.run_after(SessionTimer::presence, std::chrono::ceil<std::chrono::milliseconds>(kPresenceInterval - since),
                 [this] { on_presence_timer(); });
}

void SessionHandler::on_presence_timer() {
  presence_timer_armed_ = false;
  if (phase_ != Phase::open || !presence_held_) return;
  const protocol::Presence p = *presence_held_;
  presence_held_.reset();
  relay_presence(p, ctx_.now());
}

void SessionHandler::relay_presence(const protocol::Presence& p, Clock::time_point now) {
  presence_last_relayed_ = now;
  presence_relayed_ = true;
  protocol::PresenceUpdate u;
  u.artist = id_;
  u.name = client_name_;
  u.presence = p;
  // Encoded once; every session it goes to shares the bytes.
  ctx_.presence->publish(canvas_->name(), id_,
                         std::make_shared<const std::string>(protocol::encode_message(u)));
}

void SessionHandler::pump_presence() {
  if (phase_ != Phase::open || !presence_inbox_) return;
  // Without room the inbox keeps its wake outstanding: on_presence_written() pumps again.
  if (presence_in_flight_ >= kPresenceInFlight) return;
  for (auto& text : presence_inbox_->take(kPresenceInFlight - presence_in_flight_)) {
    ++presence_in_flight_;
    metrics_.presence_sent.add();
    out_.send_presence(std::move(text));
  }
}

void SessionHandler::on_presence_written() {
  if (presence_in_flight_ > 0) --presence_in_flight_;
  pump_presence();
}

}  // namespace deepcanvas::server_net
