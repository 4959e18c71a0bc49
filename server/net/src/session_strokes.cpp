// SessionHandler, strokes (PROTOCOL.md 3.3): whole and streamed strokes submitted to the
// canvas, their acks, and with a client id their claims in the stroke receipts: a resend is
// answered, waits for the first sending, or takes it over when that is cut short (withdrawing the
// cut part first). See session_handler.hpp and stroke_receipts.hpp.
#include "deepcanvas/server_net/session_handler.hpp"

#include <memory>
#include <string>
#include <utility>

#include "deepcanvas/base/log.hpp"

namespace deepcanvas::server_net {

using server_core::Clock;
using base::log_event;
using base::LogLevel;
// The ack (or the error that replaces it) comes from a canvas thread: it is posted to the strand.
server_core::AckFn SessionHandler::ack_fn(std::uint64_t handle, std::uint64_t serial) {
  return [post = post_, this, handle, serial](Result<server_core::StrokeDone> r) {
    post([this, handle, serial, r = std::move(r), given = Clock::now()] {
      metrics_.answer_wait_seconds.observe_seconds(
          std::chrono::duration<double>(Clock::now() - given).count());
      if (phase_ == Phase::open) on_answered(handle, serial, r);
    });
  };
}

void SessionHandler::on_answered(std::uint64_t handle, std::uint64_t serial,
                                 const Result<server_core::StrokeDone>& r) {
  // A streamed stroke answered before its stroke_end was ended by the canvas (idle, failed):
  // its slot is free now.
  if (serial != 0) {
    auto it = open_.find(handle);
    if (it != open_.end() && it->second.serial == serial && !it->second.replayed) {
      open_.erase(it);
      if (!r)
        remember_ended(handle, "as it failed (" + r.error().message + ")");
      else if (r->idle_ended)
        remember_ended(handle,
                       "after its idle timeout without samples (its paint is kept and was acked)");
      else
        remember_ended(handle, "and acked it");
    }
  }
  if (r)
    reply(protocol::Ack{handle, r->stroke_id, r->epoch});
  else
    reply_error(r.error(), {"stroke", handle});
}

namespace {
// Held by a take-over on its way to the session's strand: unless the session paints the resend
// (disarm), the claim goes back to the receipts when this is dropped (the session closed, or its
// strand dropped the post), so no claim stays in flight with nobody to settle it.
class TakenClaim {
 public:
  TakenClaim(StrokeReceipts* receipts, std::string canvas, std::string client_id,
             std::uint64_t handle, std::uint64_t withdraw)
      : receipts_(receipts),
        canvas_(std::move(canvas)),
        client_id_(std::move(client_id)),
        handle_(handle),
        withdraw_(withdraw) {}
  TakenClaim(const TakenClaim&) = delete;
  TakenClaim& operator=(const TakenClaim&) = delete;
  ~TakenClaim() {
    if (armed_)
      receipts_->give_back(canvas_, client_id_, handle_, withdraw_,
                           make_error(Errc::refused,
                                      "stroke handle " + std::to_string(handle_) +
                                          ": the resend that was to paint it closed first; "
                                          "send it again"));
  }
  void disarm() noexcept { armed_ = false; }

 private:
  StrokeReceipts* receipts_;
  std::string canvas_, client_id_;
  std::uint64_t handle_, withdraw_;
  bool armed_ = true;
};
}  // namespace

SessionHandler::ClaimStep SessionHandler::claim(std::string_view type, std::uint64_t handle,
                                                std::uint64_t serial,
                                                std::shared_ptr<ResendBuffer> resend) {
  if (!idempotent()) return ClaimStep::submit;
  StrokeReceipts::TakeOver take_over;
  if (resend)
    take_over = [post = post_, this, handle, serial, resend, receipts = ctx_.receipts,
                 canvas = std::string(canvas_->name()),
                 client = client_id_](std::uint64_t withdraw) {
      auto claim = std::make_shared<TakenClaim>(receipts, canvas, client, handle, withdraw);
      post([this, handle, serial, resend, withdraw, claim] {
        if (phase_ != Phase::open) return;
        claim->disarm();
        on_taken_over(handle, serial, *resend, withdraw);
      });
    };
  auto c = ctx_.receipts->claim(canvas_->name(), client_id_, handle, ctx_.now(),
                                ack_fn(handle, 0), std::move(take_over), id_);
  using Claimed = StrokeReceipts::Claimed;
  switch (c.kind) {
    case Claimed::fresh:
      if (c.withdraw != 0) withdraw_cut_stroke(c.withdraw, handle);
      return ClaimStep::submit;
    case Claimed::in_flight:
      return resend ? ClaimStep::waiting : ClaimStep::replayed;
    case Claimed::answered:
      on_answered(handle, serial, *c.outcome);
      return ClaimStep::replayed;
    case Claimed::refused:
      break;
  }
  reply_error(c.outcome->error(), {std::string(type), handle});
  return ClaimStep::refused;
}

void SessionHandler::on_taken_over(std::uint64_t handle, std::uint64_t serial,
                                   ResendBuffer& resend, std::uint64_t withdraw) {
  log_event(LogLevel::info, "resend_takes_over",
            {{"session", id_}, {"handle", handle}, {"withdraw", withdraw}});
  if (withdraw != 0) withdraw_cut_stroke(withdraw, handle);
  if (resend.stroke) {
    auto r = canvas_->submit_stroke(std::move(*resend.stroke), Clock::now(), settle_fn(handle, 0),
                                    artist_, history_handle(handle));
    if (!r) {
      unclaim(handle, r.error());
      reply_error(r.error(), {"stroke", handle});
    }
    return;
  }
  // Streamed: begun with the samples so far; still open here, it goes on live.
  auto it = open_.find(handle);
  const bool open = it != open_.end() && it->second.serial == serial && it->second.replayed;
  auto key = canvas_->begin_stroke(*resend.brush, std::move(resend.samples), Clock::now(),
                                   settle_fn(handle, serial), artist_, history_handle(handle));
  if (!key) {
    unclaim(handle, key.error());
    if (open) open_.erase(it);
    return reply_error(key.error(), {"stroke_begin", handle});
  }
  if (open && !resend.ended) {
    it->second.key = *key;
    it->second.replayed = false;
    it->second.waiting.reset();
  } else {
    (void)canvas_->end_stroke(*key);
  }
}

// The resend of a stroke the restart ended cut off (StrokeReceipts::restore_cut): what the restart
// kept of it is taken back first, queued as this artist's, so before the resend it precedes. If
// that fails (the history no longer holds the stroke), the resend is painted over what was kept.
void SessionHandler::withdraw_cut_stroke(std::uint64_t stroke_id, std::uint64_t handle) {
  auto logged = [canvas = std::string(canvas_->name()), stroke_id, handle](
                    Result<server_core::UndoDone> r) {
    if (r)
      base::log_event(base::LogLevel::info, "cut_stroke_withdrawn",
                      {{"canvas", canvas}, {"stroke", stroke_id}, {"handle", handle}});
    else
      base::log_event(base::LogLevel::warn, "cut_stroke_kept",
                      {{"canvas", canvas},
                       {"stroke", stroke_id},
                       {"handle", handle},
                       {"error", r.error().message}});
  };
  if (auto r = canvas_->undo(artist_, false, Clock::now(), logged, stroke_id); !r)
    logged(std::move(r).error());
}

server_core::AckFn SessionHandler::settle_fn(std::uint64_t handle, std::uint64_t serial) {
  if (!idempotent()) return ack_fn(handle, serial);
  return [receipts = ctx_.receipts, canvas = std::string(canvas_->name()), client = client_id_,
          handle, ack = ack_fn(handle, serial)](Result<server_core::StrokeDone> r) {
    receipts->settle(canvas, client, handle, r);
    ack(std::move(r));
  };
}

void SessionHandler::unclaim(std::uint64_t handle, const Error& error) {
  if (idempotent()) ctx_.receipts->release(canvas_->name(), client_id_, handle, error);
}

void SessionHandler::remember_ended(std::uint64_t handle, std::string why) {
  forget_ended(handle);
  if (ended_.size() >= kMaxEnded) ended_.erase(ended_.begin());
  ended_.emplace_back(handle, std::move(why));
}

const std::string* SessionHandler::ended_why(std::uint64_t handle) const {
  for (const auto& [h, why] : ended_)
    if (h == handle) return &why;
  return nullptr;
}

void SessionHandler::forget_ended(std::uint64_t handle) {
  std::erase_if(ended_, [handle](const auto& e) { return e.first == handle; });
}

void SessionHandler::on_stroke(protocol::DecodedStroke& m) {
  if (!may_paint("stroke", m.handle) || !within_rate("stroke", m.handle)) return;
  // Filled only if it must wait: a take-over runs on this strand, after this handler.
  auto resend = idempotent() ? std::make_shared<ResendBuffer>() : nullptr;
  switch (claim("stroke", m.handle, 0, resend)) {
    case ClaimStep::submit:
      break;
    case ClaimStep::waiting:
      resend->stroke = std::move(m.stroke);
      return;
    case ClaimStep::replayed:
    case ClaimStep::refused:
      return;
  }
  auto r = canvas_->submit_stroke(std::move(m.stroke), Clock::now(), settle_fn(m.handle, 0),
                                  artist_, history_handle(m.handle));
  if (!r) {
    unclaim(m.handle, r.error());
    reply_error(r.error(), {"stroke", m.handle});
  }
}

void SessionHandler::on_begin(protocol::DecodedStrokeBegin& m) {
  const protocol::MessageRef about{"stroke_begin", m.handle};
  if (!may_paint(about.type, m.handle)) return;
  if (open_.count(m.handle))
    return reply_error(make_error(Errc::invalid_argument,
                                  "stroke handle " + std::to_string(m.handle) + " is already open"),
                       about);
  if (open_.size() >= config_.limits.max_open_strokes)
    return reply_error(make_error(Errc::limit_exceeded,
                                  "more than " + std::to_string(config_.limits.max_open_strokes) +
                                      " streamed strokes open at once"),
                       about);
  if (!within_rate(about.type, m.handle)) return;
  forget_ended(m.handle);
  const std::uint64_t serial = next_serial_++;
  const std::size_t n = m.samples.size();
  // Filled only if it must wait: a take-over runs on this strand, after this handler.
  auto resend = idempotent() ? std::make_shared<ResendBuffer>() : nullptr;
  switch (claim(about.type, m.handle, serial, resend)) {
    case ClaimStep::submit:
      break;
    case ClaimStep::replayed:
      // Its samples and stroke_end are dropped: the stroke was claimed (and painted) before.
      open_[m.handle] = OpenStroke{0, n, serial, true, nullptr};
      return;
    case ClaimStep::waiting:
      // Kept until the first sending settles: painted from here if it settles cut.
      resend->brush = m.brush;
      resend->samples = std::move(m.samples);
      open_[m.handle] = OpenStroke{0, n, serial, true, std::move(resend)};
      return;
    case ClaimStep::refused:
      return;
  }
  auto key = canvas_->begin_stroke(m.brush, std::move(m.samples), Clock::now(),
                                   settle_fn(m.handle, serial), artist_, history_handle(m.handle));
  if (!key) {
    unclaim(m.handle, key.error());
    return reply_error(key.error(), about);
  }
  open_[m.handle] = OpenStroke{*key, n, serial, false, nullptr};
}

// The error for samples or an end naming a handle with no open stroke.
Error SessionHandler::not_open(std::uint64_t handle) const {
  if (const std::string* why = ended_why(handle))
    return make_error(Errc::refused, "stroke handle " + std::to_string(handle) +
                                         " is over: the server ended it " + *why +
                                         "; begin a new stroke to go on");
  return make_error(Errc::not_found, "no open stroke with handle " + std::to_string(handle));
}

void SessionHandler::on_samples(protocol::DecodedStrokeSamples& m) {
  const protocol::MessageRef about{"stroke_samples", m.handle};
  auto it = open_.find(m.handle);
  if (it == open_.end()) return reply_error(not_open(m.handle), about);
  if (it->second.replayed && !it->second.waiting) return;
  const std::size_t max = config_.limits.max_samples_per_stroke;
  if (it->second.samples + m.samples.size() > max) {
    // These samples are dropped and the stroke ends with what it has.
    const OpenStroke s = it->second;
    open_.erase(it);
    remember_ended(m.handle, "when it passed " + std::to_string(max) + " samples");
    if (s.waiting)
      s.waiting->ended = true;
    else
      (void)canvas_->end_stroke(s.key);
    return reply_error(
        make_error(Errc::limit_exceeded, "stroke longer than " + std::to_string(max) +
                                             " samples: these samples were dropped and the stroke "
                                             "ended"),
        about);
  }
  it->second.samples += m.samples.size();
  if (it->second.waiting) return it->second.waiting->samples.append(m.samples);
  auto r = canvas_->add_samples(it->second.key, std::move(m.samples));
  if (!r) reply_error(r.error(), about);
}

void SessionHandler::on_end(const protocol::StrokeEnd& m) {
  const protocol::MessageRef about{"stroke_end", m.handle};
  auto it = open_.find(m.handle);
  if (it == open_.end()) {
    const Error e = not_open(m.handle);
    forget_ended(m.handle);  // the client knows now: the handle is free again
    return reply_error(e, about);
  }
  const OpenStroke s = it->second;
  open_.erase(it);
  if (s.waiting) s.waiting->ended = true;
  if (s.replayed) return;
  auto r = canvas_->end_stroke(s.key);
  if (!r) reply_error(r.error(), about);
}

}  // namespace deepcanvas::server_net
