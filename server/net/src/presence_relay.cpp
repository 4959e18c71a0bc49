// PresenceRelay and PresenceInbox (presence_relay.hpp).
#include "deepcanvas/server_net/presence_relay.hpp"

#include <algorithm>

namespace deepcanvas::server_net {

// ---------------------------------------------------------------------------- PresenceInbox

bool PresenceInbox::put(std::uint64_t artist, PresenceText text, bool gone) {
  std::lock_guard lock(mutex_);
  auto it = latest_.find(artist);
  if (gone && !told_.count(artist)) {
    // This member never heard of the artist: nothing to take back, and its pending presence
    // (if any) is stale now. Dropping both keeps the inbox bounded by the artists it was told of.
    if (it != latest_.end()) {
      latest_.erase(it);
      std::erase(order_, artist);
      if (coalesced_) coalesced_->add();
    }
    return false;
  }
  if (it != latest_.end()) {
    it->second = Entry{std::move(text), gone};
    if (coalesced_) coalesced_->add();
  } else {
    latest_.emplace(artist, Entry{std::move(text), gone});
    order_.push_back(artist);
  }
  if (wake_outstanding_) return false;
  wake_outstanding_ = true;
  return true;
}

std::vector<PresenceText> PresenceInbox::take(std::size_t max) {
  std::vector<PresenceText> out;
  std::lock_guard lock(mutex_);
  wake_outstanding_ = false;
  while (out.size() < max && !order_.empty()) {
    const std::uint64_t artist = order_.front();
    order_.pop_front();
    auto it = latest_.find(artist);
    if (it == latest_.end()) continue;
    if (it->second.gone)
      told_.erase(artist);
    else
      told_.insert(artist);
    out.push_back(std::move(it->second.text));
    latest_.erase(it);
  }
  return out;
}

std::size_t PresenceInbox::pending() const {
  std::lock_guard lock(mutex_);
  return latest_.size();
}

// ---------------------------------------------------------------------------- PresenceRelay

void PresenceRelay::fan_out(Canvas& c, std::uint64_t from, const PresenceText& text, bool gone,
                            std::vector<std::function<void()>>& wakes) {
  for (auto& [id, m] : c.members)
    if (id != from && m.inbox->put(from, text, gone)) wakes.push_back(m.wake);
}

std::shared_ptr<PresenceInbox> PresenceRelay::join(std::string_view canvas, std::uint64_t member,
                                                   std::function<void()> wake) {
  auto inbox = std::make_shared<PresenceInbox>(metrics_.coalesced);
  bool woken = false;
  {
    std::lock_guard lock(mutex_);
    auto it = canvases_.find(canvas);
    if (it == canvases_.end()) it = canvases_.emplace(std::string(canvas), Canvas{}).first;
    Canvas& c = it->second;
    for (const auto& [artist, text] : c.latest)
      if (artist != member && inbox->put(artist, text, false)) woken = true;
    c.members[member] = Member{inbox, wake};
  }
  if (woken && wake) wake();
  return inbox;
}

void PresenceRelay::leave(std::string_view canvas, std::uint64_t member, PresenceText gone_text) {
  std::vector<std::function<void()>> wakes;
  {
    std::lock_guard lock(mutex_);
    auto it = canvases_.find(canvas);
    if (it == canvases_.end()) return;
    Canvas& c = it->second;
    c.members.erase(member);
    if (c.latest.erase(member) && gone_text) {
      if (metrics_.published) metrics_.published->add();
      fan_out(c, member, gone_text, true, wakes);
    }
    if (c.members.empty() && c.latest.empty()) canvases_.erase(it);
  }
  for (auto& w : wakes)
    if (w) w();
}

void PresenceRelay::publish(std::string_view canvas, std::uint64_t member, PresenceText text) {
  std::vector<std::function<void()>> wakes;
  {
    std::lock_guard lock(mutex_);
    auto it = canvases_.find(canvas);
    // A member that has left publishes nothing (its gone has been sent).
    if (it == canvases_.end() || !it->second.members.count(member)) return;
    Canvas& c = it->second;
    c.latest[member] = text;
    if (metrics_.published) metrics_.published->add();
    fan_out(c, member, text, false, wakes);
  }
  for (auto& w : wakes)
    if (w) w();
}

std::size_t PresenceRelay::members(std::string_view canvas) const {
  std::lock_guard lock(mutex_);
  auto it = canvases_.find(canvas);
  return it == canvases_.end() ? 0 : it->second.members.size();
}

}  // namespace deepcanvas::server_net
