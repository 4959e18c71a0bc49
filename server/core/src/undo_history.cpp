#include "deepcanvas/server_core/undo_history.hpp"

#include <algorithm>
#include <limits>
#include <string>

namespace deepcanvas::server_core {

namespace {
constexpr std::uint32_t kMagic = 0x48554344u;  // "DCUH" little-endian
constexpr std::uint32_t kVersion = 1;

struct Writer {
  std::vector<std::uint8_t> out;
  void u8(std::uint8_t v) { out.push_back(v); }
  void u32(std::uint32_t v) {
    for (int i = 0; i < 4; ++i) out.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
  }
  void u64(std::uint64_t v) {
    for (int i = 0; i < 8; ++i) out.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
  }
};
struct Reader {
  std::span<const std::uint8_t> in;
  std::size_t at = 0;
  bool ok = true;
  std::uint64_t le(int n) {
    if (!ok || in.size() - at < static_cast<std::size_t>(n)) {
      ok = false;
      return 0;
    }
    std::uint64_t v = 0;
    for (int i = 0; i < n; ++i) v |= std::uint64_t{in[at + static_cast<std::size_t>(i)]} << (8 * i);
    at += static_cast<std::size_t>(n);
    return v;
  }
};
}  // namespace

UndoHistory UndoHistory::without_artists(std::set<std::uint64_t> named) {
  UndoHistory h(UndoLimits{std::numeric_limits<std::uint32_t>::max(),
                           std::numeric_limits<std::uint64_t>::max(),
                           std::numeric_limits<std::uint64_t>::max()});
  h.merged_ = true;
  h.named_ = std::move(named);
  return h;
}

void UndoHistory::trim(Artist& a) {
  while (a.undo.size() > limits_.depth) {
    bytes_ -= a.undo.front().diff.size();
    a.undo.pop_front();
    a.evicted = true;
  }
}

void UndoHistory::fit_budget() {
  while (bytes_ > limits_.max_bytes) {
    // Each side is in the order its entries came (seq grows), so the oldest entry of all is at
    // the front of one of them.
    Artist* owner = nullptr;
    bool from_redo = false;
    std::uint64_t oldest = std::numeric_limits<std::uint64_t>::max();
    for (auto& [id, a] : artists_) {
      if (!a.undo.empty() && a.undo.front().seq < oldest) {
        oldest = a.undo.front().seq;
        owner = &a;
        from_redo = false;
      }
      if (!a.redo.empty() && a.redo.front().seq < oldest) {
        oldest = a.redo.front().seq;
        owner = &a;
        from_redo = true;
      }
    }
    if (!owner) break;
    if (from_redo) {
      bytes_ -= owner->redo.front().diff.size();
      owner->redo.erase(owner->redo.begin());
    } else {
      bytes_ -= owner->undo.front().diff.size();
      owner->undo.pop_front();
      owner->evicted = true;
    }
  }
}

void UndoHistory::set_limits(const UndoLimits& limits) {
  limits_ = limits;
  for (auto& [id, a] : artists_) trim(a);
  fit_budget();
}

void UndoHistory::stroke_done(std::uint64_t artist, std::uint64_t stroke_id,
                              std::vector<std::uint8_t> diff) {
  Entry e;
  e.stroke_id = stroke_id;
  if (diff.size() > limits_.max_stroke_bytes)
    e.too_large = true;
  else
    e.diff = std::move(diff);
  push(artist, std::move(e));
}

void UndoHistory::stroke_too_large(std::uint64_t artist, std::uint64_t stroke_id) {
  Entry e;
  e.stroke_id = stroke_id;
  e.too_large = true;
  push(artist, std::move(e));
}

void UndoHistory::push(std::uint64_t artist, Entry e) {
  if (limits_.depth == 0) return;
  if (merged_) {
    if (!named_.empty() && !named_.count(e.stroke_id)) return;
    artist = 0;
  }
  Artist& a = artists_[artist];
  if (!merged_) {
    for (const Entry& r : a.redo) bytes_ -= r.diff.size();
    a.redo.clear();
  }
  bytes_ += e.diff.size();
  e.seq = std::max(next_seq_, e.stroke_id);  // ids grow with time, so seq follows them
  next_seq_ = e.seq + 1;
  a.undo.push_back(std::move(e));
  trim(a);
  fit_budget();
}

Result<const UndoHistory::Entry*> UndoHistory::next(std::uint64_t artist, bool redo) const {
  if (limits_.depth == 0) return make_error(Errc::refused, "this canvas keeps no undo history");
  const auto it = artists_.find(artist);
  if (redo) {
    if (it == artists_.end() || it->second.redo.empty())
      return make_error(Errc::not_found,
                        "nothing to redo (a new stroke after an undo clears what could be redone)");
    return &it->second.redo.back();
  }
  if (it == artists_.end() || it->second.undo.empty()) {
    if (it != artists_.end() && it->second.evicted)
      return make_error(Errc::limit_exceeded,
                        "nothing more to undo: the history keeps your last " +
                            std::to_string(limits_.depth) + " strokes (undo_depth) within " +
                            std::to_string(limits_.max_bytes >> 20) +
                            " MiB of changes for everyone's strokes (undo_max_bytes)");
    return make_error(Errc::not_found, "nothing to undo");
  }
  const Entry& e = it->second.undo.back();
  if (e.too_large)
    return make_error(Errc::limit_exceeded,
                      "stroke " + std::to_string(e.stroke_id) +
                          " changed more cells than the history keeps for one stroke (" +
                          std::to_string(limits_.max_stroke_bytes) +
                          " bytes, undo_max_stroke_bytes): it cannot be undone");
  return &e;
}

std::optional<std::pair<std::uint64_t, const UndoHistory::Entry*>> UndoHistory::find(
    std::uint64_t stroke_id, bool redo) const {
  for (const auto& [artist, a] : artists_) {
    if (redo) {
      for (const Entry& e : a.redo)
        if (e.stroke_id == stroke_id) return std::make_pair(artist, &e);
    } else {
      for (const Entry& e : a.undo)
        if (e.stroke_id == stroke_id) return std::make_pair(artist, &e);
    }
  }
  return std::nullopt;
}

void UndoHistory::moved(std::uint64_t artist, std::uint64_t stroke_id, bool redo,
                        std::vector<std::uint8_t> revert_diff) {
  auto it = artists_.find(artist);
  if (it == artists_.end()) return;
  Artist& a = it->second;
  Entry e;
  e.stroke_id = stroke_id;
  e.diff = std::move(revert_diff);
  e.seq = next_seq_++;
  const auto take_out = [&](const Entry& x) {
    if (x.stroke_id != stroke_id) return false;
    bytes_ -= x.diff.size();
    return true;
  };
  bytes_ += e.diff.size();
  if (redo) {
    std::erase_if(a.redo, take_out);
    a.undo.push_back(std::move(e));
    trim(a);
  } else {
    std::erase_if(a.undo, take_out);
    a.redo.push_back(std::move(e));
  }
  fit_budget();
}

std::uint64_t UndoHistory::entries() const noexcept {
  std::uint64_t n = 0;
  for (const auto& [artist, a] : artists_) n += a.undo.size() + a.redo.size();
  return n;
}

std::vector<std::uint8_t> UndoHistory::save() const {
  Writer w;
  w.u32(kMagic);
  w.u32(kVersion);
  w.u32(limits_.depth);
  w.u64(limits_.max_stroke_bytes);
  w.u32(static_cast<std::uint32_t>(artists_.size()));
  auto entry = [&](const Entry& e) {
    w.u64(e.stroke_id);
    w.u8(e.too_large ? 1 : 0);
    w.u32(static_cast<std::uint32_t>(e.diff.size()));
    w.out.insert(w.out.end(), e.diff.begin(), e.diff.end());
  };
  for (const auto& [artist, a] : artists_) {
    w.u64(artist);
    w.u8(a.evicted ? 1 : 0);
    w.u32(static_cast<std::uint32_t>(a.undo.size()));
    w.u32(static_cast<std::uint32_t>(a.redo.size()));
    for (const Entry& e : a.undo) entry(e);
    for (const Entry& e : a.redo) entry(e);
  }
  return std::move(w.out);
}

Result<UndoHistory> UndoHistory::load(std::span<const std::uint8_t> bytes) {
  auto bad = [](const std::string& what) {
    return make_error(Errc::malformed, "undo history: " + what);
  };
  Reader r{bytes};
  if (r.le(4) != kMagic) return bad("bad magic");
  const std::uint64_t version = r.le(4);
  if (version != kVersion) return bad("unsupported version " + std::to_string(version));
  UndoLimits limits;
  limits.depth = static_cast<std::uint32_t>(r.le(4));
  limits.max_stroke_bytes = r.le(8);
  UndoHistory h(limits);
  const std::uint64_t artists = r.le(4);
  for (std::uint64_t i = 0; i < artists && r.ok; ++i) {
    const std::uint64_t id = r.le(8);
    Artist& a = h.artists_[id];
    a.evicted = r.le(1) != 0;
    const std::uint64_t nu = r.le(4), nr = r.le(4);
    // Each entry takes at least 13 bytes: a count past what is left is malformed.
    if (!r.ok || (nu + nr) * 13 > bytes.size() - r.at) return bad("entry count past the end");
    for (std::uint64_t k = 0; k < nu + nr && r.ok; ++k) {
      Entry e;
      e.stroke_id = r.le(8);
      e.too_large = r.le(1) != 0;
      const std::uint64_t n = r.le(4);
      if (!r.ok || n > bytes.size() - r.at) return bad("entry past the end");
      e.diff.assign(bytes.begin() + static_cast<std::ptrdiff_t>(r.at),
                    bytes.begin() + static_cast<std::ptrdiff_t>(r.at + n));
      r.at += n;
      h.bytes_ += e.diff.size();
      // The order entries came in is not saved: a stroke's id stands for it.
      e.seq = e.stroke_id;
      h.next_seq_ = std::max(h.next_seq_, e.stroke_id + 1);
      if (k < nu)
        a.undo.push_back(std::move(e));
      else
        a.redo.push_back(std::move(e));
    }
  }
  if (!r.ok) return bad("truncated");
  if (r.at != bytes.size()) return bad("trailing bytes");
  return h;
}

}  // namespace deepcanvas::server_core
