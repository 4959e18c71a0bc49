// StrokeReceipts against a brute-force reference: random claims, settles and releases of a few
// client ids on two canvases, with the window, the client cap and the expiry small enough to be
// reached often. The reference keeps every receipt forever; the table must agree with it on
// everything it still remembers, refuse only what its bounds say, and answer every waiter once.
#include <gtest/gtest.h>

#include <map>
#include <optional>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "deepcanvas/server_net/stroke_receipts.hpp"

namespace deepcanvas::test {
namespace {

using server_net::ReceiptLimits;
using server_net::StrokeReceipts;
using Claimed = StrokeReceipts::Claimed;
using server_core::StrokeDone;
using namespace std::chrono_literals;

TEST(StrokeReceipts, ClaimSettleAndResend) {
  StrokeReceipts r;
  const auto t = server_core::Clock::now();
  int answers = 0;
  StrokeReceipts::Outcome seen = make_error(Errc::internal, "none");
  auto waiter = [&](StrokeReceipts::Outcome o) {
    ++answers;
    seen = std::move(o);
  };
  EXPECT_EQ(r.claim("c", "a", 1, t, waiter).kind, Claimed::fresh);
  EXPECT_EQ(r.claim("c", "a", 1, t, waiter).kind, Claimed::in_flight);  // a resend in flight
  EXPECT_EQ(r.claim("c", "b", 1, t, waiter).kind, Claimed::fresh);      // another client id
  EXPECT_EQ(r.claim("d", "a", 1, t, waiter).kind, Claimed::fresh);      // another canvas
  EXPECT_EQ(answers, 0);
  r.settle("c", "a", 1, StrokeDone{7, 3});
  ASSERT_EQ(answers, 1);
  ASSERT_TRUE(seen.ok());
  EXPECT_EQ(seen->stroke_id, 7u);
  auto again = r.claim("c", "a", 1, t, waiter);
  ASSERT_EQ(again.kind, Claimed::answered);
  EXPECT_EQ((*again.outcome)->stroke_id, 7u);
  EXPECT_EQ((*again.outcome)->epoch, 3u);
  EXPECT_EQ(answers, 1);  // an answered claim keeps no waiter

  // A failed stroke's error is what its resends get.
  r.settle("c", "b", 1, make_error(Errc::limit_exceeded, "too many cells"));
  auto failed = r.claim("c", "b", 1, t, waiter);
  ASSERT_EQ(failed.kind, Claimed::answered);
  EXPECT_EQ(failed.outcome->error().code, Errc::limit_exceeded);

  // A released claim (never submitted) is forgotten: its waiters get the error, a resend is new.
  answers = 0;
  EXPECT_EQ(r.claim("c", "a", 2, t, waiter).kind, Claimed::fresh);
  EXPECT_EQ(r.claim("c", "a", 2, t, waiter).kind, Claimed::in_flight);
  r.release("c", "a", 2, make_error(Errc::limit_exceeded, "queue full"));
  ASSERT_EQ(answers, 1);
  EXPECT_EQ(seen.error().code, Errc::limit_exceeded);
  EXPECT_EQ(r.claim("c", "a", 2, t, waiter).kind, Claimed::fresh);
  // Settling twice, or what was never claimed, changes nothing.
  r.settle("c", "a", 1, StrokeDone{99, 99});
  r.settle("c", "zz", 5, StrokeDone{99, 99});
  EXPECT_EQ((*r.claim("c", "a", 1, t, waiter).outcome)->stroke_id, 7u);
}

// After a restart: the names the canvas's history kept are answered by client id (through its
// artist key) and handle, on their canvas only; other handles of that client id are new.
TEST(StrokeReceipts, RestoredNamesAreAnsweredAfterARestart) {
  StrokeReceipts r;
  const auto t = server_core::Clock::now();
  const std::uint64_t artist = server_net::artist_key("painter-1");
  EXPECT_NE(artist, server_net::artist_key("painter-2"));
  EXPECT_NE(artist & (std::uint64_t{1} << 63), 0u);  // apart from session ids
  // Newest first: handle 6 was used twice, and names stroke 41, the newer.
  r.restore("c",
            {{artist, 6, 41}, {artist, 5, 40}, {artist, 6, 30}, {server_net::artist_key("x"), 7, 42}},
            9);
  int answers = 0;
  auto waiter = [&](StrokeReceipts::Outcome) { ++answers; };
  auto a = r.claim("c", "painter-1", 6, t, waiter);
  ASSERT_EQ(a.kind, Claimed::answered);
  ASSERT_TRUE(a.outcome->ok());
  EXPECT_EQ((*a.outcome)->stroke_id, 41u);
  EXPECT_EQ((*a.outcome)->epoch, 9u);
  EXPECT_EQ(r.claim("c", "painter-1", 5, t, waiter).kind, Claimed::answered);
  EXPECT_EQ(r.claim("c", "painter-1", 7, t, waiter).kind, Claimed::fresh);  // x's handle 7
  EXPECT_EQ(r.claim("d", "painter-1", 5, t, waiter).kind, Claimed::fresh);  // another canvas
  EXPECT_EQ(r.claim("c", "painter-2", 5, t, waiter).kind, Claimed::fresh);
  EXPECT_EQ(answers, 0);
}

// A stroke a limit stopped before the restart is answered as its first sending was: with
// limit_exceeded (naming the stroke), not an ack, and it is not claimed fresh (which would
// paint it again).
TEST(StrokeReceipts, ARestoredStoppedStrokeIsAnsweredWithItsError) {
  StrokeReceipts r;
  const auto t = server_core::Clock::now();
  const std::uint64_t artist = server_net::artist_key("painter-1");
  server_core::StrokeName stopped{artist, 4, 33};
  stopped.stopped = true;
  // Handle 4's newest stroke is the stopped one; an older one with the same handle was acked.
  r.restore("c", {stopped, {artist, 3, 32}, {artist, 4, 20}}, 9);
  auto waiter = [](StrokeReceipts::Outcome) { ADD_FAILURE() << "no waiter for an answer"; };
  auto a = r.claim("c", "painter-1", 4, t, waiter);
  ASSERT_EQ(a.kind, Claimed::answered);
  ASSERT_FALSE(a.outcome->ok());
  EXPECT_EQ(a.outcome->error().code, Errc::limit_exceeded);
  EXPECT_NE(a.outcome->error().message.find("stroke 33"), std::string::npos)
      << a.outcome->error().message;
  auto b = r.claim("c", "painter-1", 3, t, waiter);
  ASSERT_EQ(b.kind, Claimed::answered);
  ASSERT_TRUE(b.outcome->ok());
  EXPECT_EQ((*b.outcome)->stroke_id, 32u);
}

// After a restart: a stroke the restart ended cut off is claimed fresh by its resend, once, with
// the stroke to withdraw first; on its canvas and by its client id only. A resend released
// (the canvas refused it at once) withdraws nothing the second time: the withdrawal was queued.
TEST(StrokeReceipts, ACutOffStrokesResendWithdrawsItOnce) {
  StrokeReceipts r;
  const auto t = server_core::Clock::now();
  const std::uint64_t artist = server_net::artist_key("painter-1");
  r.restore_cut("c", {{artist, 6, 41}, {artist, 8, 43}});
  auto none = [](StrokeReceipts::Outcome) {};
  EXPECT_EQ(r.claim("d", "painter-1", 6, t, none).withdraw, 0u);  // another canvas
  EXPECT_EQ(r.claim("c", "painter-2", 6, t, none).withdraw, 0u);  // another client id
  const auto a = r.claim("c", "painter-1", 6, t, none);
  EXPECT_EQ(a.kind, Claimed::fresh);
  EXPECT_EQ(a.withdraw, 41u);
  EXPECT_EQ(r.claim("c", "painter-1", 6, t, none).kind, Claimed::in_flight);
  r.release("c", "painter-1", 6, make_error(Errc::limit_exceeded, "queue full"));
  const auto again = r.claim("c", "painter-1", 6, t, none);
  EXPECT_EQ(again.kind, Claimed::fresh);
  EXPECT_EQ(again.withdraw, 0u);
  EXPECT_EQ(r.claim("c", "painter-1", 7, t, none).withdraw, 0u);
  EXPECT_EQ(r.claim("c", "painter-1", 8, t, none).withdraw, 43u);
}

// Within a run: a stroke whose connection closed before its end is remembered as cut once the
// canvas settles it, and its resend is claimed fresh with it to withdraw, once. A stroke settled
// before its connection closed, one whose resend was already waiting, and one that failed keep
// their answer.
TEST(StrokeReceipts, AStrokeLeftOpenByAClosedConnectionIsWithdrawnByItsResend) {
  StrokeReceipts r;
  const auto t = server_core::Clock::now();
  auto none = [](StrokeReceipts::Outcome) {};
  ASSERT_EQ(r.claim("c", "p", 3, t, none).kind, Claimed::fresh);
  r.mark_cut("c", "p", 3);
  r.settle("c", "p", 3, StrokeDone{17, 5, false});
  const auto resend = r.claim("c", "p", 3, t, none);
  EXPECT_EQ(resend.kind, Claimed::fresh);
  EXPECT_EQ(resend.withdraw, 17u);
  EXPECT_EQ(r.claim("d", "p", 3, t, none).withdraw, 0u);  // another canvas
  r.settle("c", "p", 3, StrokeDone{18, 6, false});
  const auto again = r.claim("c", "p", 3, t, none);
  ASSERT_EQ(again.kind, Claimed::answered);
  EXPECT_EQ((*again.outcome)->stroke_id, 18u);

  // Settled before the close: marking it changes nothing.
  ASSERT_EQ(r.claim("c", "p", 4, t, none).kind, Claimed::fresh);
  r.settle("c", "p", 4, StrokeDone{19, 7, false});
  r.mark_cut("c", "p", 4);
  EXPECT_EQ((*r.claim("c", "p", 4, t, none).outcome)->stroke_id, 19u);

  // A resend already waiting gets the ack of what came (it was told it is in flight).
  ASSERT_EQ(r.claim("c", "p", 5, t, none).kind, Claimed::fresh);
  std::uint64_t heard = 0;
  ASSERT_EQ(r.claim("c", "p", 5, t, [&](StrokeReceipts::Outcome o) { heard = o->stroke_id; }).kind,
            Claimed::in_flight);
  r.mark_cut("c", "p", 5);
  r.settle("c", "p", 5, StrokeDone{20, 8, false});
  EXPECT_EQ(heard, 20u);
  EXPECT_EQ(r.claim("c", "p", 5, t, none).kind, Claimed::answered);

  // Ended by the idle timeout (its connection may have gone silently): cut too.
  ASSERT_EQ(r.claim("c", "p", 7, t, none).kind, Claimed::fresh);
  r.settle("c", "p", 7, StrokeDone{21, 9, true});
  EXPECT_EQ(r.claim("c", "p", 7, t, none).withdraw, 21u);

  // A failed stroke keeps its error as the answer.
  ASSERT_EQ(r.claim("c", "p", 6, t, none).kind, Claimed::fresh);
  r.mark_cut("c", "p", 6);
  r.settle("c", "p", 6, make_error(Errc::limit_exceeded, "too many cells"));
  const auto failed = r.claim("c", "p", 6, t, none);
  ASSERT_EQ(failed.kind, Claimed::answered);
  EXPECT_EQ(failed.outcome->error().code, Errc::limit_exceeded);
}

// A resend that can paint the stroke itself (a TakeOver) waits while the first sending is in
// flight; when that settles cut, the claim passes to it with the part to withdraw, and other
// waiting resends get its answer. The first sender's connection closing afterwards does not mark
// the taken claim (it is not that sender's any more); a taken claim given back is cut again.
TEST(StrokeReceipts, AWaitingResendTakesOverAStrokeSettledCut) {
  StrokeReceipts r;
  const auto t = server_core::Clock::now();
  auto none = [](StrokeReceipts::Outcome) {};
  constexpr std::uint64_t kFirst = 1, kResend = 2;
  ASSERT_EQ(r.claim("c", "p", 3, t, none, {}, kFirst).kind, Claimed::fresh);
  std::vector<std::uint64_t> taken;
  const auto take = [&](std::uint64_t withdraw) { taken.push_back(withdraw); };
  ASSERT_EQ(r.claim("c", "p", 3, t, none, take, kResend).kind, Claimed::in_flight);
  std::uint64_t heard = 0;
  ASSERT_EQ(r.claim("c", "p", 3, t, [&](StrokeReceipts::Outcome o) { heard = o->stroke_id; })
                .kind,
            Claimed::in_flight);
  r.settle("c", "p", 3, StrokeDone{17, 5, true});  // the idle timeout ended it
  ASSERT_EQ(taken, std::vector<std::uint64_t>{17});
  EXPECT_EQ(heard, 0u) << "answered with the cut part's ack";
  r.mark_cut("c", "p", 3, kFirst);  // the first sender's connection closes now
  r.settle("c", "p", 3, StrokeDone{19, 6, false});  // the resend, painted whole
  EXPECT_EQ(heard, 19u);
  const auto again = r.claim("c", "p", 3, t, none);
  ASSERT_EQ(again.kind, Claimed::answered);
  EXPECT_EQ((*again.outcome)->stroke_id, 19u);

  // The taker's own connection closing cuts it like any holder's.
  ASSERT_EQ(r.claim("c", "p", 4, t, none, {}, kFirst).kind, Claimed::fresh);
  ASSERT_EQ(r.claim("c", "p", 4, t, none, take, kResend).kind, Claimed::in_flight);
  r.mark_cut("c", "p", 4, kFirst);
  r.settle("c", "p", 4, StrokeDone{20, 7, false});
  ASSERT_EQ(taken.back(), 20u);
  r.mark_cut("c", "p", 4, kResend);
  r.settle("c", "p", 4, StrokeDone{22, 8, false});
  EXPECT_EQ(r.claim("c", "p", 4, t, none).withdraw, 22u);

  // Given back (the taker closed before it painted): cut again, with the first part to withdraw.
  ASSERT_EQ(r.claim("c", "p", 5, t, none, {}, kFirst).kind, Claimed::fresh);
  ASSERT_EQ(r.claim("c", "p", 5, t, none, take, kResend).kind, Claimed::in_flight);
  std::optional<StrokeReceipts::Outcome> told;
  ASSERT_EQ(r.claim("c", "p", 5, t, [&](StrokeReceipts::Outcome o) { told = o; }).kind,
            Claimed::in_flight);
  r.settle("c", "p", 5, StrokeDone{23, 9, true});
  ASSERT_EQ(taken.back(), 23u);
  r.give_back("c", "p", 5, 23, make_error(Errc::refused, "closed first"));
  ASSERT_TRUE(told.has_value());
  EXPECT_FALSE(told->ok());
  const auto next = r.claim("c", "p", 5, t, none);
  EXPECT_EQ(next.kind, Claimed::fresh);
  EXPECT_EQ(next.withdraw, 23u);
}

TEST(StrokeReceipts, WindowForgetsTheLowestAnsweredAndRefusesPastInFlight) {
  ReceiptLimits limits;
  limits.per_client = 3;
  StrokeReceipts r(limits);
  const auto t = server_core::Clock::now();
  auto none = [](StrokeReceipts::Outcome) {};
  for (std::uint64_t h = 1; h <= 3; ++h) ASSERT_EQ(r.claim("c", "a", h, t, none).kind, Claimed::fresh);
  // Three in flight: a fourth would forget stroke 1 before it is answered.
  auto full = r.claim("c", "a", 4, t, none);
  ASSERT_EQ(full.kind, Claimed::refused);
  EXPECT_EQ(full.outcome->error().code, Errc::limit_exceeded);
  r.settle("c", "a", 1, StrokeDone{1, 1});
  EXPECT_EQ(r.claim("c", "a", 4, t, none).kind, Claimed::fresh);  // forgets 1
  auto old = r.claim("c", "a", 1, t, none);
  ASSERT_EQ(old.kind, Claimed::refused);
  EXPECT_EQ(old.outcome->error().code, Errc::refused);
  EXPECT_EQ(r.claim("c", "a", 0, t, none).kind, Claimed::refused);  // below the forgotten one
  EXPECT_EQ(r.claim("c", "a", 2, t, none).kind, Claimed::in_flight);  // still remembered
}

TEST(StrokeReceipts, ClientIdsExpireAndAreCappedButNotWhileInFlight) {
  ReceiptLimits limits;
  limits.max_clients = 2;
  limits.expiry = 60s;
  StrokeReceipts r(limits);
  auto t = server_core::Clock::now();
  auto none = [](StrokeReceipts::Outcome) {};
  ASSERT_EQ(r.claim("c", "a", 1, t, none).kind, Claimed::fresh);  // in flight
  r.touch("c", "b", t);
  r.touch("c", "x", t + 1s);  // past the cap: b (idle, least recent) goes, a stays in flight
  EXPECT_EQ(r.clients(), 2u);
  EXPECT_EQ(r.claim("c", "a", 1, t + 2s, none).kind, Claimed::in_flight);
  r.settle("c", "a", 1, StrokeDone{5, 5});
  t += 10min;
  r.touch("c", "y", t);  // a and x have expired
  EXPECT_EQ(r.clients(), 1u);
  EXPECT_EQ(r.claim("c", "a", 1, t, none).kind, Claimed::fresh);  // forgotten
}

// Strokes cut by closed connections are receipts of their client ids: a client using a new
// client id for every stroke it cuts short cannot grow the table past max_clients, a cut of an
// expired client id is forgotten with it, and past per_client handles a cut one is refused.
TEST(StrokeReceipts, CutStrokesAreBoundedLikeAnyReceipt) {
  ReceiptLimits limits;
  limits.max_clients = 4;
  limits.per_client = 2;
  limits.expiry = 60s;
  StrokeReceipts r(limits);
  auto t = server_core::Clock::now();
  auto none = [](StrokeReceipts::Outcome) {};
  for (int i = 0; i < 100; ++i) {
    const std::string id = "hostile-" + std::to_string(i);
    ASSERT_EQ(r.claim("c", id, 1, t, none).kind, Claimed::fresh);
    r.mark_cut("c", id, 1);
    r.settle("c", id, 1, StrokeDone{static_cast<std::uint64_t>(100 + i), 1, false});
    EXPECT_LE(r.clients(), limits.max_clients + 1);  // + the one in flight at the claim
  }
  // The newest ones are still remembered as cut; the first was forgotten with its client id.
  EXPECT_EQ(r.claim("c", "hostile-99", 1, t, none).withdraw, 199u);
  EXPECT_EQ(r.claim("c", "hostile-0", 1, t, none).withdraw, 0u);

  // Expiry takes a cut stroke with its client id.
  ASSERT_EQ(r.claim("c", "gone", 1, t, none).kind, Claimed::fresh);
  r.mark_cut("c", "gone", 1);
  r.settle("c", "gone", 1, StrokeDone{7, 1, false});
  r.touch("c", "other", t + 10min);
  EXPECT_EQ(r.claim("c", "gone", 1, t + 10min, none).withdraw, 0u);

  // Past per_client handles a cut stroke is forgotten like an answered one: refused.
  ASSERT_EQ(r.claim("c", "w", 1, t, none).kind, Claimed::fresh);
  r.mark_cut("c", "w", 1);
  r.settle("c", "w", 1, StrokeDone{8, 1, false});
  for (std::uint64_t h = 2; h <= 3; ++h) {
    ASSERT_EQ(r.claim("c", "w", h, t, none).kind, Claimed::fresh);
    r.settle("c", "w", h, StrokeDone{8 + h, 1, false});
  }
  EXPECT_EQ(r.claim("c", "w", 1, t, none).kind, Claimed::refused);
}

// The property: random claims (new handles and resends), settles and releases by a few client
// ids on two canvases, against a reference that forgets nothing. With client ids neither capped
// nor expired, a stroke once answered is never claimed fresh again (the window refuses what it
// forgot), every answer equals the reference's, and every waiter is called exactly once with the
// outcome of its stroke. With a window larger than the traffic, nothing is ever refused.
TEST(StrokeReceipts, AgreesWithAReferenceThatForgetsNothing) {
  for (std::uint64_t seed = 1; seed <= 40; ++seed) {
    std::mt19937_64 rng(seed);
    ReceiptLimits limits;
    const bool small_window = seed % 2;
    limits.per_client = small_window ? 1 + rng() % 6 : 100000;
    limits.max_clients = 100;
    limits.expiry = std::chrono::hours(1000);
    StrokeReceipts table(limits);
    const auto t = server_core::Clock::now();

    using Name = std::tuple<std::string, std::string, std::uint64_t>;
    struct Ref {
      std::optional<StrokeReceipts::Outcome> outcome;  // empty: in flight
      int waiters = 0;
    };
    std::map<Name, Ref> ref;  // claimed and not released, by name
    std::map<Name, std::vector<std::uint64_t>> heard;  // stroke ids (0: an error) waiters got
    std::vector<Name> in_flight;
    std::uint64_t next_id = 1;
    const std::vector<std::string> canvases = {"c", "d"}, ids = {"a", "b", "e"};
    std::map<std::pair<std::string, std::string>, std::uint64_t> top;  // highest handle used

    for (int step = 0; step < 2000; ++step) {
      const int op = static_cast<int>(rng() % 10);
      if (op < 6 || in_flight.empty()) {
        const std::string& cv = canvases[rng() % 2];
        const std::string& id = ids[rng() % ids.size()];
        auto& hi = top[{cv, id}];
        // Mostly the next handle; sometimes a resend of one of the last eight.
        const std::uint64_t h = (hi == 0 || rng() % 3 == 0) ? ++hi : hi - rng() % std::min<std::uint64_t>(hi, 8);
        const Name name{cv, id, h};
        auto c = table.claim(cv, id, h, t, [&heard, name](StrokeReceipts::Outcome o) {
          heard[name].push_back(o ? o->stroke_id : 0);
        });
        auto it = ref.find(name);
        switch (c.kind) {
          case Claimed::fresh:
            ASSERT_EQ(it, ref.end()) << "painted twice: handle " << h << ", seed " << seed;
            ref[name] = Ref{};
            in_flight.push_back(name);
            break;
          case Claimed::in_flight:
            ASSERT_NE(it, ref.end());
            ASSERT_FALSE(it->second.outcome);
            ++it->second.waiters;
            break;
          case Claimed::answered: {
            ASSERT_NE(it, ref.end());
            ASSERT_TRUE(it->second.outcome);
            const auto& want = *it->second.outcome;
            ASSERT_EQ(c.outcome->ok(), want.ok());
            if (want) {
              ASSERT_EQ((*c.outcome)->stroke_id, want->stroke_id);
            }
            break;
          }
          case Claimed::refused: {
            ASSERT_TRUE(small_window) << "refused with a window larger than the traffic";
            ASSERT_TRUE(c.outcome && !c.outcome->ok());
            const Errc code = c.outcome->error().code;
            ASSERT_TRUE(code == Errc::refused || code == Errc::limit_exceeded);
            break;
          }
        }
      } else {
        const std::size_t k = rng() % in_flight.size();
        const Name name = in_flight[k];
        in_flight.erase(in_flight.begin() + static_cast<std::ptrdiff_t>(k));
        const auto& [cv, id, h] = name;
        const int waiters = ref[name].waiters;
        std::uint64_t expect = 0;
        if (op == 9) {
          table.release(cv, id, h, make_error(Errc::limit_exceeded, "queue full"));
          ref.erase(name);  // never painted: a resend is a new attempt
        } else if (op == 8) {
          StrokeReceipts::Outcome o = make_error(Errc::out_of_memory, "full");
          table.settle(cv, id, h, o);
          ref[name].outcome = o;
        } else {
          expect = next_id++;
          StrokeReceipts::Outcome o = StrokeDone{expect, 1};
          table.settle(cv, id, h, o);
          ref[name].outcome = o;
        }
        ASSERT_EQ(heard[name], std::vector<std::uint64_t>(static_cast<std::size_t>(waiters), expect));
        heard.erase(name);
      }
    }
    EXPECT_EQ(table.clients(), top.size());
  }
}

}  // namespace
}  // namespace deepcanvas::test
