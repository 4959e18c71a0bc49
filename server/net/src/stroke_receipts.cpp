// StrokeReceipts: resent strokes are painted once (stroke_receipts.hpp).
#include "deepcanvas/server_net/stroke_receipts.hpp"

#include <algorithm>

namespace deepcanvas::server_net {

std::uint64_t artist_key(std::string_view client_id) noexcept {
  return server_core::fnv1a64({reinterpret_cast<const std::uint8_t*>(client_id.data()),
                               client_id.size()}) |
         (std::uint64_t{1} << 63);
}

void StrokeReceipts::restore(std::string_view canvas,
                             const std::vector<server_core::StrokeName>& names,
                             std::uint64_t epoch) {
  std::lock_guard lock(mutex_);
  // Newest first: a handle a client id used more than once names its newest stroke.
  for (const auto& n : names) {
    auto& answers = restored_[{std::string(canvas), n.artist}];
    if (answers.count(n.handle)) continue;
    if (n.stopped) {
      answers.emplace(n.handle,
                      make_error(Errc::limit_exceeded,
                                 "stroke " + std::to_string(n.stroke_id) +
                                     " was stopped by a limit before the server restarted; what "
                                     "it painted until then is kept"));
    } else {
      answers.emplace(n.handle, server_core::StrokeDone{n.stroke_id, epoch, false});
    }
  }
}

void StrokeReceipts::restore_cut(std::string_view canvas,
                                 const std::vector<server_core::StrokeName>& names) {
  std::lock_guard lock(mutex_);
  for (const auto& n : names)
    cut_[{std::string(canvas), n.artist}].insert_or_assign(n.handle, n.stroke_id);
}

void StrokeReceipts::mark_cut(std::string_view canvas, std::string_view client_id,
                              std::uint64_t handle, std::uint64_t owner) {
  std::lock_guard lock(mutex_);
  auto c = clients_.find(Key{std::string(canvas), std::string(client_id)});
  if (c == clients_.end()) return;
  auto r = c->second.receipts.find(handle);
  // Only the holder's: a claim a resend took over (settle) is no longer the closed sender's.
  if (r != c->second.receipts.end() && r->second.in_flight() && r->second.owner == owner)
    r->second.cut = true;
}

// per_client 0 would leave no room for the claim being made: at least 1.
StrokeReceipts::StrokeReceipts(ReceiptLimits limits)
    : limits_{std::max<std::size_t>(1, limits.per_client), limits.max_clients, limits.expiry} {}

StrokeReceipts::Client& StrokeReceipts::client_locked(std::string_view canvas,
                                                      std::string_view client_id,
                                                      Clock::time_point now) {
  Key key{std::string(canvas), std::string(client_id)};
  auto it = clients_.find(key);
  if (it == clients_.end()) {
    lru_.push_front(key);
    it = clients_.emplace(std::move(key), Client{}).first;
    it->second.lru = lru_.begin();
  } else {
    lru_.splice(lru_.begin(), lru_, it->second.lru);
  }
  it->second.last_seen = std::max(it->second.last_seen, now);
  return it->second;
}

// From the least recently seen: expired client ids, then any past max_clients, never one with
// strokes in flight (their waiters must be answered).
void StrokeReceipts::forget_idle_locked(Clock::time_point now) {
  std::size_t excess = clients_.size() > limits_.max_clients ? clients_.size() - limits_.max_clients
                                                              : 0;
  for (auto it = lru_.end(); it != lru_.begin();) {
    --it;
    auto c = clients_.find(*it);
    const bool expired = now - c->second.last_seen >= limits_.expiry;
    if (!expired && excess == 0) break;
    if (c->second.in_flight > 0) continue;
    clients_.erase(c);
    it = lru_.erase(it);
    if (excess > 0) --excess;
  }
}

StrokeReceipts::ClaimResult StrokeReceipts::claim(std::string_view canvas,
                                                  std::string_view client_id,
                                                  std::uint64_t handle, Clock::time_point now,
                                                  Waiter waiter, TakeOver take_over,
                                                  std::uint64_t owner) {
  std::lock_guard lock(mutex_);
  Client& c = client_locked(canvas, client_id, now);
  ClaimResult result;
  if (auto it = c.receipts.find(handle); it != c.receipts.end()) {
    if (it->second.outcome) {
      result.kind = Claimed::answered;
      result.outcome = *it->second.outcome;
    } else if (it->second.cut_stroke != 0) {
      // Settled as cut: this resend is painted whole once the cut part is withdrawn.
      result.kind = Claimed::fresh;
      result.withdraw = it->second.cut_stroke;
      it->second = Receipt{};
      it->second.owner = owner;
      ++c.in_flight;
    } else {
      result.kind = Claimed::in_flight;
      it->second.waiters.push_back({std::move(waiter), std::move(take_over), owner});
    }
    return result;
  }
  if (!restored_.empty()) {
    auto r = restored_.find({std::string(canvas), artist_key(client_id)});
    if (r != restored_.end()) {
      if (auto h = r->second.find(handle); h != r->second.end()) {
        result.kind = Claimed::answered;
        result.outcome = h->second;
        return result;
      }
    }
  }
  result.kind = Claimed::refused;
  if (c.forgotten && handle <= *c.forgotten) {
    result.outcome = make_error(
        Errc::refused, "stroke handle " + std::to_string(handle) + " is not above " +
                           std::to_string(*c.forgotten) + ", the highest handle of client id '" +
                           std::string(client_id) + "' the server no longer remembers (it keeps " +
                           std::to_string(limits_.per_client) +
                           "): whether it was painted is unknown; handles of a client id must "
                           "increase");
    return result;
  }
  if (c.receipts.size() >= limits_.per_client) {
    auto oldest = c.receipts.begin();
    if (oldest->second.in_flight()) {
      result.outcome = make_error(
          Errc::limit_exceeded,
          "more than " + std::to_string(limits_.per_client) + " strokes of client id '" +
              std::string(client_id) + "' since its oldest unanswered one (stroke_receipts)");
      return result;
    }
    c.forgotten = std::max(c.forgotten.value_or(0), oldest->first);
    c.receipts.erase(oldest);
  }
  c.receipts.emplace(handle, Receipt{}).first->second.owner = owner;
  ++c.in_flight;
  forget_idle_locked(now);
  result.kind = Claimed::fresh;
  if (!cut_.empty()) {
    auto r = cut_.find({std::string(canvas), artist_key(client_id)});
    if (r != cut_.end()) {
      if (auto h = r->second.find(handle); h != r->second.end()) {
        result.withdraw = h->second;
        r->second.erase(h);
        if (r->second.empty()) cut_.erase(r);
      }
    }
  }
  return result;
}

std::vector<StrokeReceipts::Waiter> StrokeReceipts::finish_locked(std::string_view canvas,
                                                                  std::string_view client_id,
                                                                  std::uint64_t handle,
                                                                  const Outcome* keep) {
  auto c = clients_.find(Key{std::string(canvas), std::string(client_id)});
  if (c == clients_.end()) return {};
  auto r = c->second.receipts.find(handle);
  if (r == c->second.receipts.end() || !r->second.in_flight()) return {};
  std::vector<Waiter> waiters;
  for (auto& w : r->second.waiters) waiters.push_back(std::move(w.answer));
  --c->second.in_flight;
  if (keep) {
    r->second.outcome = *keep;
    r->second.waiters.clear();
  } else {
    c->second.receipts.erase(r);
  }
  return waiters;
}

// An in-flight claim settled as cut: remembered with the stroke its resend withdraws; a cut that
// painted nothing (0) leaves nothing to withdraw, and the next claim is plainly fresh.
void StrokeReceipts::remember_cut_locked(Client& c, std::map<std::uint64_t, Receipt>::iterator r,
                                         std::uint64_t stroke_id) {
  --c.in_flight;
  if (stroke_id != 0) {
    r->second = Receipt{};
    r->second.cut_stroke = stroke_id;
  } else {
    c.receipts.erase(r);
  }
}

void StrokeReceipts::settle(std::string_view canvas, std::string_view client_id,
                            std::uint64_t handle, const Outcome& outcome) {
  std::vector<Waiter> waiters;
  TakeOver taker;
  {
    std::lock_guard lock(mutex_);
    // A stroke cut short (its connection closed, or the idle timeout ended it: a connection
    // that went silently looks so to the server): not remembered as answered but as cut, so a
    // resend paints it whole. A live sender got the ack and never sends the handle again.
    auto c = clients_.find(Key{std::string(canvas), std::string(client_id)});
    if (c != clients_.end() && outcome) {
      auto r = c->second.receipts.find(handle);
      if (r != c->second.receipts.end() && r->second.in_flight() &&
          (r->second.cut || outcome->idle_ended)) {
        auto& resends = r->second.waiters;
        const auto taking = std::find_if(resends.begin(), resends.end(),
                                         [](const Resend& w) { return bool(w.take_over); });
        if (taking != resends.end()) {
          // A resend that can paint it waits: the claim passes to it, still in flight; the
          // other resends keep waiting, now on its answer.
          taker = std::move(taking->take_over);
          r->second.owner = taking->owner;
          r->second.cut = false;
          resends.erase(taking);
        } else if (resends.empty()) {
          // Kept in the client id's receipts, so the per_client, max_clients and expiry bounds
          // hold for cut strokes too.
          remember_cut_locked(c->second, r, outcome->stroke_id);
          return;
        }
      }
    }
    if (!taker) waiters = finish_locked(canvas, client_id, handle, &outcome);
  }
  if (taker) return taker(outcome->stroke_id);
  for (auto& w : waiters) w(outcome);
}

void StrokeReceipts::give_back(std::string_view canvas, std::string_view client_id,
                               std::uint64_t handle, std::uint64_t withdraw, const Error& error) {
  std::vector<Waiter> waiters;
  {
    std::lock_guard lock(mutex_);
    auto c = clients_.find(Key{std::string(canvas), std::string(client_id)});
    if (c == clients_.end()) return;
    auto r = c->second.receipts.find(handle);
    if (r == c->second.receipts.end() || !r->second.in_flight()) return;
    for (auto& w : r->second.waiters) waiters.push_back(std::move(w.answer));
    remember_cut_locked(c->second, r, withdraw);
  }
  for (auto& w : waiters) w(Outcome(error));
}

void StrokeReceipts::release(std::string_view canvas, std::string_view client_id,
                             std::uint64_t handle, const Error& error) {
  std::vector<Waiter> waiters;
  {
    std::lock_guard lock(mutex_);
    waiters = finish_locked(canvas, client_id, handle, nullptr);
  }
  for (auto& w : waiters) w(Outcome(error));
}

void StrokeReceipts::touch(std::string_view canvas, std::string_view client_id,
                           Clock::time_point now) {
  std::lock_guard lock(mutex_);
  client_locked(canvas, client_id, now);
  forget_idle_locked(now);
}

std::size_t StrokeReceipts::clients() const {
  std::lock_guard lock(mutex_);
  return clients_.size();
}

}  // namespace deepcanvas::server_net
