// PresenceRelay: the artists' presence (PROTOCOL.md 3.9) passed between the sessions of a canvas.
//
// Every session of a canvas, painter or viewer, is a member of its canvas's relay from its
// accepted hello to its end, with a PresenceInbox. A painter's session publishes its presence
// (already encoded as the server-to-client "presence" message, after its own 50 ms rate limit:
// session_presence.cpp) and the relay puts it into every other member's inbox; a member that
// joins later gets the latest presence of every artist present at once. When a painter that
// published leaves, the others get its "gone" update.
//
// Bounded for slow readers: an inbox holds at most one update per artist (a newer one replaces
// the one not yet taken: counted in ServerMetrics::presence_coalesced), and a "gone" for an artist
// the member was never given is dropped with that artist's pending update. So an inbox never
// holds more than the artists present plus those that left after the member was told of them;
// the member takes from it only as its socket accepts writes (SessionHandler keeps at most
// kPresenceInFlight presence messages in its transport's queue).
//
// No Asio here: waking a member is the `wake` function it joined with (the session posts to its
// strand). Threading: every member function of PresenceRelay and PresenceInbox is thread-safe.
// The relay's lock is taken before an inbox's, never the other way; wake functions run with no
// lock held.
#pragma once

#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "deepcanvas/server_core/metrics.hpp"

namespace deepcanvas::server_net {

// An encoded server-to-client "presence" message, shared by every member it goes to.
using PresenceText = std::shared_ptr<const std::string>;

// One member's pending presence updates, at most one per artist, in the order the artists first
// became pending.
class PresenceInbox {
 public:
  // `coalesced` (may be null) counts updates replaced or dropped before they were taken.
  explicit PresenceInbox(server_core::Counter* coalesced) : coalesced_(coalesced) {}

  // Adds the update of `artist` (replacing one of it not yet taken). A `gone` update of an artist
  // this member was never given drops that artist's pending update instead. Returns true when the
  // owner must be woken: the inbox has something and no wake is outstanding.
  bool put(std::uint64_t artist, PresenceText text, bool gone);
  // The owner (on its strand): clears the outstanding wake, then takes up to `max` updates,
  // oldest first. After take() a later put() wakes the owner again.
  std::vector<PresenceText> take(std::size_t max);
  std::size_t pending() const;

 private:
  struct Entry {
    PresenceText text;
    bool gone = false;
  };
  mutable std::mutex mutex_;
  std::deque<std::uint64_t> order_;
  std::unordered_map<std::uint64_t, Entry> latest_;
  std::unordered_set<std::uint64_t> told_;  // artists given a presence and not yet their gone
  bool wake_outstanding_ = false;
  server_core::Counter* coalesced_;
};

class PresenceRelay {
 public:
  struct Metrics {
    server_core::Counter* published = nullptr;  // updates published (gone included)
    server_core::Counter* coalesced = nullptr;  // updates replaced in an inbox before taken
  };
  PresenceRelay() = default;
  explicit PresenceRelay(Metrics metrics) : metrics_(metrics) {}

  // `member` (the session id, = its artist id) joins `canvas`. Its inbox receives the latest
  // presence of every artist on the canvas now and every update published from now on but its
  // own. `wake` runs (on the publishing thread, no lock held) when the inbox needs attention.
  std::shared_ptr<PresenceInbox> join(std::string_view canvas, std::uint64_t member,
                                      std::function<void()> wake);
  // Leaves `canvas`. `gone_text`: the member's encoded "gone" update, published to the others
  // if the member ever published a presence (ignored otherwise).
  void leave(std::string_view canvas, std::uint64_t member, PresenceText gone_text);
  // The presence of artist `member` (a member of `canvas`) to every other member of it.
  void publish(std::string_view canvas, std::uint64_t member, PresenceText text);
  // Members of `canvas` (tests).
  std::size_t members(std::string_view canvas) const;

 private:
  struct Member {
    std::shared_ptr<PresenceInbox> inbox;
    std::function<void()> wake;
  };
  struct Canvas {
    std::map<std::uint64_t, Member> members;
    std::map<std::uint64_t, PresenceText> latest;  // by artist: what a joining member gets
  };
  // Puts into every member's inbox but `from`'s; collects the wakes to run after the lock.
  void fan_out(Canvas& c, std::uint64_t from, const PresenceText& text, bool gone,
               std::vector<std::function<void()>>& wakes);

  mutable std::mutex mutex_;
  std::map<std::string, Canvas, std::less<>> canvases_;
  Metrics metrics_;
};

}  // namespace deepcanvas::server_net
