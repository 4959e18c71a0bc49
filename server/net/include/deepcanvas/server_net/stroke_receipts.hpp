// StrokeReceipts: what the server remembers of each client id's strokes, so that a stroke resent
// after a reconnect is painted once (PROTOCOL.md 3.3.1, hello "client_id").
//
// A stroke is named by (canvas, client id, handle). The first session to send it claims the
// name and submits the stroke; its outcome (the ack's stroke_id and epoch, or the error) is
// settled here when the canvas answers. A later claim of the same name paints nothing: it gets
// the outcome at once when it is known, or its callback is called with it when it comes (the
// stroke is in flight, e.g. the first connection broke before the ack).
//
// Bounded memory, and why each bound cannot lose an answer:
//   * per client id, the receipts of its `per_client` highest claimed handles; a claim that would
//     forget a stroke still in flight is refused instead (limit_exceeded), so no waiter is ever
//     dropped. Handles at or below the highest forgotten one get `refused` (the server can no
//     longer tell whether they were painted): with a client id, handles must increase.
//   * at most `max_clients` client ids (all canvases); past that the least recently seen one
//     with nothing in flight is forgotten. Client ids with strokes in flight are kept (there are
//     at most as many as sessions), so the bound may be passed by at most the session count.
//   * a client id not seen (no hello, no stroke) for `expiry` is forgotten, unless it has
//     strokes in flight.
// A receipt is about 100 bytes: the defaults (256 x 1024) bound the table near 26 MB.
//
// Across a restart: a durable canvas's history names the strokes its senders ended
// (storage stroke_names: artist key and handle). restore() seeds them as answered, so that a
// client that missed an ack when the server went away and resends the stroke after the restart
// gets the ack, not a second copy of the stroke; one a limit stopped (StrokeName::stopped) gets
// limit_exceeded, as its first sending did, and its kept paint is not painted again. Restored names are looked up by the artist key
// a client id gives (artist_key) and are bounded by what the store loads (65536 a canvas).
// A stroke cut off by the stop (its end not durable) is not named as ended: the restart ended it
// with what was durable. restore_cut() seeds those a client id sent, so that the first claim of
// one (its resend) is fresh with ClaimResult::withdraw set: the caller takes the kept part back
// (CanvasService::undo of that stroke) before it submits the resend, which then shows once.
//
// Within one run: a stroke whose connection closed before its end is ended by the canvas with
// what came, so its resend (the whole stroke) would otherwise be answered with the ack of that
// part and the rest of the artist's stroke lost. mark_cut() names such a stroke: once the canvas
// settles it, it is remembered as cut (not answered), and its resend is claimed fresh with the
// part to withdraw, as after a restart. So is a stroke the canvas ended after its idle timeout
// (StrokeDone::idle_ended): a connection that went silently (a dropped mobile link) is still
// open to the server then, while its client reconnects and resends. A resend that arrives before
// the canvas settled the stroke waits (in_flight); if it gave a TakeOver and the stroke settles
// cut, the claim passes to it: take_over(stroke to withdraw) is called instead of its waiter, the
// receipt stays in flight for it, and it withdraws the part and paints the stroke whole, then
// settles (or releases, or gives the claim back with give_back()). A cut stroke is a receipt
// of its client id like any other: within `per_client` of its handles (past it, its resend is
// refused like any forgotten handle), forgotten with the client id (max_clients, expiry).
//
// Threading: every member is thread-safe (one mutex). Callbacks (the waiters given to claim())
// are called without the lock held, on the thread that calls settle() or release(), which for
// the server is a canvas's stroke thread: they must be short (the session handler's post to its
// strand).
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <list>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/server_core/canvas_service.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"

namespace deepcanvas::server_net {

// The artist key a client id gives: the canvas orders a client id's strokes as one artist's
// across reconnects, and its history names them by it. FNV-1a-64 of the id with the top bit set
// (a session without a client id is keyed by its session id, a small counter).
std::uint64_t artist_key(std::string_view client_id) noexcept;

struct ReceiptLimits {
  std::size_t per_client = 256;  // handles remembered per client id (welcome.limits.stroke_receipts)
  std::size_t max_clients = 1024;  // client ids remembered, all canvases
  std::chrono::seconds expiry{600};  // a client id unseen this long is forgotten
};

class StrokeReceipts {
 public:
  using Clock = server_core::Clock;
  using Outcome = Result<server_core::StrokeDone>;
  using Waiter = std::function<void(Outcome)>;
  // A waiting resend that can paint the stroke itself: called (instead of its Waiter) with the
  // stroke to withdraw (0: none) when the stroke it waits on settles cut. The callee then holds
  // a fresh claim: it must settle(), release() or give_back() it.
  using TakeOver = std::function<void(std::uint64_t withdraw)>;

  explicit StrokeReceipts(ReceiptLimits limits = {});
  StrokeReceipts(const StrokeReceipts&) = delete;
  StrokeReceipts& operator=(const StrokeReceipts&) = delete;

  enum class Claimed {
    fresh,      // new: the caller submits the stroke, then settle() or release()
    answered,   // painted (or failed) before: ClaimResult::outcome is its result
    in_flight,  // claimed before and not yet answered: the waiter will get the outcome
    refused,    // not accepted: ClaimResult::outcome holds the error (too old, too many open)
  };
  struct ClaimResult {
    Claimed kind = Claimed::fresh;
    std::optional<Outcome> outcome;  // answered, refused
    // fresh only: the stroke a restart ended (restore_cut) or a closed connection left unended
    // (mark_cut) that this claim resends, to be withdrawn before the resend is submitted; 0: none.
    std::uint64_t withdraw = 0;
  };

  // Claims the stroke (canvas, client_id, handle). `waiter` and `take_over` (may be empty) are
  // kept only for in_flight. `owner` names the claimant (a session), for mark_cut: a fresh
  // claim is held by it, and an in-flight one passes to it with a take-over.
  ClaimResult claim(std::string_view canvas, std::string_view client_id, std::uint64_t handle,
                    Clock::time_point now, Waiter waiter, TakeOver take_over = {},
                    std::uint64_t owner = 0);
  // The canvas answered a fresh claim: remembers the outcome and calls the waiters with it.
  void settle(std::string_view canvas, std::string_view client_id, std::uint64_t handle,
              const Outcome& outcome);
  // A fresh claim whose stroke was not submitted (the canvas refused it at once): forgets the
  // claim, so a resend is a new attempt, and calls the waiters that came meanwhile with `error`.
  void release(std::string_view canvas, std::string_view client_id, std::uint64_t handle,
               const Error& error);
  // Seeds the canvas's strokes named in its history (after a restart, before any session) as
  // answered with an ack of `stroke_id` at `epoch` (the restored canvas's first), or for a
  // stopped one with limit_exceeded naming the stroke. `names` come newest first; of two with
  // one handle the first wins.
  void restore(std::string_view canvas, const std::vector<server_core::StrokeName>& names,
               std::uint64_t epoch);
  // Seeds the canvas's strokes that the restart ended, cut off, and a client id had sent
  // (storage RestoreReport::cut_stroke_names): the first fresh claim of each name carries its
  // stroke id in ClaimResult::withdraw.
  void restore_cut(std::string_view canvas, const std::vector<server_core::StrokeName>& names);
  // The connection that claimed the stroke closed before its end: once settled with an ack, the
  // stroke is remembered as cut, and the next claim of it carries it in ClaimResult::withdraw. A
  // stroke already settled, or with resends waiting, is left as it is.
  // Only the claim's holder (`owner`, as given to claim()) can mark it: a claim a resend took
  // over is no longer the closed sender's.
  void mark_cut(std::string_view canvas, std::string_view client_id, std::uint64_t handle,
                std::uint64_t owner = 0);
  // A claim passed by TakeOver whose resend could not be painted (its connection closed first):
  // the stroke is remembered as cut again, with `withdraw` (0: forgotten), for the next resend;
  // resends still waiting on it get `error`.
  void give_back(std::string_view canvas, std::string_view client_id, std::uint64_t handle,
                 std::uint64_t withdraw, const Error& error);
  // A hello with this client id: keeps it from expiring.
  void touch(std::string_view canvas, std::string_view client_id, Clock::time_point now);

  // Client ids remembered (tests, metrics).
  std::size_t clients() const;
  const ReceiptLimits& limits() const noexcept { return limits_; }

 private:
  using Key = std::pair<std::string, std::string>;  // (canvas, client id)
  struct Resend {
    Waiter answer;
    TakeOver take_over;  // may be empty
    std::uint64_t owner = 0;
  };
  struct Receipt {
    std::optional<Outcome> outcome;  // empty: in flight, or settled as cut
    std::vector<Resend> waiters;
    bool cut = false;  // mark_cut: its sender's connection closed before its end
    std::uint64_t owner = 0;  // who holds the claim in flight (claim(), a take-over)
    // Settled as cut (the canvas ended it short; nobody resent it yet): the stroke its resend
    // withdraws. Not an answer: the next claim of the handle is fresh.
    std::uint64_t cut_stroke = 0;
    bool in_flight() const noexcept { return !outcome && cut_stroke == 0; }
  };
  struct Client {
    std::map<std::uint64_t, Receipt> receipts;  // by handle
    std::optional<std::uint64_t> forgotten;      // the highest handle no longer remembered
    std::size_t in_flight = 0;
    Clock::time_point last_seen{};
    std::list<Key>::iterator lru;  // its place in lru_
  };

  void remember_cut_locked(Client& c, std::map<std::uint64_t, Receipt>::iterator r,
                           std::uint64_t stroke_id);
  Client& client_locked(std::string_view canvas, std::string_view client_id,
                        Clock::time_point now);
  void forget_idle_locked(Clock::time_point now);
  // Removes the receipt and returns its waiters (to call without the lock).
  std::vector<Waiter> finish_locked(std::string_view canvas, std::string_view client_id,
                                    std::uint64_t handle, const Outcome* keep);

  const ReceiptLimits limits_;
  mutable std::mutex mutex_;
  std::map<Key, Client> clients_;
  // restore(): (canvas, artist key) -> handle -> the answer.
  std::map<std::pair<std::string, std::uint64_t>, std::map<std::uint64_t, Outcome>> restored_;
  // restore_cut(): (canvas, artist key) -> handle -> the stroke to withdraw; taken by its claim.
  // Bounded by what the store loads. Strokes cut within this run are kept in their client id's
  // receipts instead (Receipt::cut_stroke), under that client id's bounds.
  std::map<std::pair<std::string, std::uint64_t>, std::map<std::uint64_t, std::uint64_t>> cut_;
  std::list<Key> lru_;  // most recently seen first
};

}  // namespace deepcanvas::server_net
