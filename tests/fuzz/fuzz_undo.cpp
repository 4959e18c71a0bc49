// libFuzzer: the undo history's decoders of stored bytes (a checkpoint's undo history and each
// stroke's encoded change, undo_history.hpp and cell_diff.hpp). Input = one mode byte + bytes.
// Mode bit 0 clear: decode_cell_diff on a small canvas; what decodes must re-encode to bytes that
// decode to the same changes. Set: UndoHistory::load; what loads must save to bytes that load
// and save again identically. Mode bit 1 set (an import's cells, cell_paste.hpp): decode_cell_paste;
// what decodes must re-encode to bytes that decode to the same cells.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <span>

#include "deepcanvas/server_core/cell_diff.hpp"
#include "deepcanvas/server_core/cell_paste.hpp"
#include "deepcanvas/server_core/undo_history.hpp"

namespace sc = deepcanvas::server_core;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  const std::span<const std::uint8_t> in(data + 1, size - 1);
  if ((data[0] & 2) != 0) {
    sc::OctreeConfig canvas;
    canvas.max_depth = 12;
    auto p = sc::decode_cell_paste(in, canvas, 1u << 16);
    if (!p) return 0;
    const auto again = sc::decode_cell_paste(sc::encode_cell_paste(*p), canvas, 1u << 16);
    if (!again || again->size() != p->size()) std::abort();
    for (std::size_t i = 0; i < p->size(); ++i)
      if (!(again->cells[i].cell == p->cells[i].cell) || again->cells[i].rgba != p->cells[i].rgba)
        std::abort();
    return 0;
  }
  if ((data[0] & 1) == 0) {
    sc::OctreeConfig canvas;
    canvas.max_depth = 12;
    auto d = sc::decode_cell_diff(in, canvas, 1u << 16);
    if (!d) return 0;
    // The encoder writes each depth's cells in address order.
    std::stable_sort(d->changes.begin(), d->changes.end(),
                     [](const auto& a, const auto& b) { return sc::cell_order(a.cell, b.cell); });
    const auto again = sc::decode_cell_diff(sc::encode_cell_diff(*d), canvas, 1u << 16);
    if (!again || again->size() != d->size()) std::abort();
    for (std::size_t i = 0; i < d->size(); ++i)
      if (!(again->changes[i].cell == d->changes[i].cell) ||
          !(again->changes[i].before == d->changes[i].before) ||
          !(again->changes[i].after == d->changes[i].after))
        std::abort();
    return 0;
  }
  auto h = sc::UndoHistory::load(in);
  if (!h) return 0;
  const auto saved = h->save();
  auto back = sc::UndoHistory::load(saved);
  if (!back || back->save() != saved) std::abort();
  return 0;
}
