// The stroke thread's imports: a paste's turn (stroke_thread.hpp; CanvasService::paste).
#include "stroke_thread.hpp"

namespace deepcanvas::server_core {

using base::log_event;
using base::LogLevel;

// A paste's turn: the painter is not busy (strokes of other artists may be open: the paste
// overwrites their cells, and they paint on over it). Done at once, recorded as an event, kept in
// the artist's undo history like a stroke, and answered with the next epoch once durable.
void CanvasService::Impl::StrokeThread::run_paste(std::uint64_t id) {
  keep_changes();
  PendingStroke& s = strokes.at(id);
  const std::uint64_t artist = s.artist;
  ImportFn done = std::move(s.import_done);
  const std::shared_ptr<const CellPaste> cells = std::move(s.paste);
  strokes.erase(id);
  PasteStats st;
  auto change = painter->paste(*cells, &st);
  if (!change) {
    metrics.imports_refused.add();
    log_event(LogLevel::warn, "import_refused",
              {{"canvas", config.name}, {"stroke", id}, {"error", change.error().message}});
    if (done) replies.push_back([done = std::move(done), e = change.error()] { done(e); });
    return;
  }
  metrics.imports.add();
  metrics.cells_changed.add(st.cells_changed);
  if (change->too_large)
    history.stroke_too_large(artist, id);
  else
    history.stroke_done(artist, id, encode_cell_diff(*change));
  log_event(LogLevel::info, "import_applied",
            {{"canvas", config.name},
             {"stroke", id},
             {"cells", st.cells},
             {"cells_changed", st.cells_changed}});
  std::uint64_t seq = 0;
  if (config.on_stroke_event || config.journal) {
    StrokeEvent e;
    e.kind = StrokeEvent::Kind::paste;
    e.stroke_id = id;
    e.artist = artist;
    e.paste = encode_cell_paste(*cells);
    if (config.journal) seq = last_seq = config.journal->append(e, artist);
    if (config.on_stroke_event) config.on_stroke_event(e);
  }
  if (done) answer_when_durable(seq, std::move(done), ImportDone{id, epoch + 1, st});
}

}  // namespace deepcanvas::server_core
