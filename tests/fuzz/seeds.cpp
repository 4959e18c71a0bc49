// protocol_fuzz_seeds KIND DIR: writes a small seed corpus for fuzz_KIND into DIR (valid inputs
// of every shape, so the fuzzer starts from deep inside the decoders).
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/protocol/frame_bundle.hpp"
#include "deepcanvas/protocol/messages.hpp"
#include "deepcanvas/server_core/cell_diff.hpp"
#include "deepcanvas/server_core/cell_paste.hpp"
#include "deepcanvas/server_core/undo_history.hpp"

namespace dp = deepcanvas::protocol;

namespace {

bool write(const std::string& dir, int n, const void* data, std::size_t size) {
  std::ofstream out(dir + "/seed_" + std::to_string(n), std::ios::binary);
  out.write(static_cast<const char*>(data), static_cast<std::streamsize>(size));
  return static_cast<bool>(out);
}

std::vector<dp::Message> messages() {
  dp::Stroke s;
  s.brush.colour[1] = 0.25f;
  s.samples = {{1.5, -2.0, 3.25, 0.05f, 0.75f, 10}, {1.6, -2.0, 3.25, 0.05f, 1.0f, 20}};
  dp::Hello hello;
  hello.role = dp::Role::painter;
  hello.token = "token-123";
  hello.canvas = "main";
  hello.client_name = "seed";
  dp::Welcome welcome;
  welcome.canvas = "main";
  welcome.epoch = 42;
  dp::ErrorMessage error{deepcanvas::Errc::unsupported, "protocol version 2", "hello", 7, true};
  dp::Presence presence;
  presence.cursor_on_canvas = true;
  presence.cursor = {0.5, 1.5, -2.0};
  presence.eye = {0.0, 1.6, 5.0};
  presence.target = {0.0, 1.6, 0.0};
  presence.colour = {1.0f, 0.5f, 0.0f, 1.0f};
  presence.size_m = 0.02;
  presence.mode = dp::BrushMode::smudge;
  presence.painting = true;
  dp::Presence off_canvas = presence;
  off_canvas.cursor_on_canvas = false;
  const dp::PresenceUpdate update{12, "ann", false, presence};
  const dp::PresenceUpdate gone{12, "ann", true, {}};
  return {hello,
          welcome,
          dp::StrokeMessage{1, s},
          dp::StrokeBegin{2, s.brush, s.samples},
          dp::StrokeSamples{2, s.samples},
          dp::StrokeEnd{2},
          dp::Ack{1, 100, 5},
          dp::PickUp{3, {1.0, 2.0, -3.0}},
          dp::PickUpReply{3, {0.5f, 0.25f, 1.0f}, 0.75f, 12},
          error,
          dp::StatsRequest{},
          dp::Stats{1, 2, 3, 4, 5, 6, 7},
          dp::EpochEnd{5, 3, true},
          presence,
          off_canvas,
          update,
          gone};
}

// Block frames of every shape: full frames under each option set, and delta frames.
struct SeedFrame {
  std::vector<std::uint8_t> bytes;
  bool delta = false;
};
std::vector<SeedFrame> seed_frames() {
  std::vector<SeedFrame> out;
  for (const std::uint32_t cells : {8u, 64u, 520u}) {
    std::vector<std::uint32_t> fc(cells), colour(cells), gp(cells / 8);
    std::vector<std::uint8_t> df(cells / 8);
    std::vector<std::uint64_t> mask((cells / 8 + 63) / 64, 0x5);
    for (std::uint32_t i = 0; i < cells; ++i) {
      fc[i] = i % 3 ? dp::kNoCellWire : 4096 + 8 * i;
      colour[i] = 0xFF000000u | (i * 2654435761u >> 8);
    }
    for (std::uint32_t g = 0; g < cells / 8; ++g) {
      gp[g] = g == 0 ? dp::kNoCellWire : 100 + g;
      df[g] = static_cast<std::uint8_t>(g % 25);
    }
    dp::BlockView v;
    v.block_id = 1;
    v.version = 3;
    v.epoch = 9;
    v.first_cell = 4096;
    v.cell_count = cells;
    v.first_child = fc;
    v.colour = colour;
    v.group_parent = gp;
    v.depth_flags = df;
    v.neighbour_mask = mask;
    for (const auto& opt :
         {dp::BlockEncodeOptions{1, true, true}, dp::BlockEncodeOptions{1, false, false},
          dp::BlockEncodeOptions{3, false, true}, dp::BlockEncodeOptions{1, true, false}}) {
      dp::BlockEncoder enc(opt);
      auto f = enc.encode(v);
      if (f) out.push_back({std::move(*f), false});
    }
    std::vector<std::uint32_t> fc2 = fc, colour2 = colour;
    for (std::uint32_t i = 0; i < cells; i += 7) colour2[i] ^= 0x00A0B0C0u;
    fc2[0] = 4096 + 8 * 1000;
    dp::BlockView base = v, now = v;
    now.version = 5;
    now.first_child = fc2;
    now.colour = colour2;
    base.neighbour_mask = {};
    for (const auto& opt :
         {dp::BlockEncodeOptions{3, true, true}, dp::BlockEncodeOptions{3, false, true},
          dp::BlockEncodeOptions{1, true, false}, dp::BlockEncodeOptions{1, false, false}}) {
      dp::BlockEncoder enc(opt);
      std::vector<std::uint8_t> f;
      if (enc.encode_delta(now, base, f)) out.push_back({std::move(f), true});
    }
  }
  return out;
}

int block_seeds(const std::string& dir) {
  int n = 0;
  const auto frames = seed_frames();
  if (frames.size() != 24) return 1;
  for (const auto& f : frames) {
    // Delta frames: the fuzzer resolves them against a base it derives from the input; mode 4
    // makes the checksum fit that base.
    const auto modes =
        f.delta ? std::vector<std::uint8_t>{0, 1, 3, 4, 7} : std::vector<std::uint8_t>{0, 1, 3};
    for (const std::uint8_t mode : modes) {
      std::vector<std::uint8_t> input{mode};
      input.insert(input.end(), f.bytes.begin(), f.bytes.end());
      if (!write(dir, n++, input.data(), input.size())) return 1;
    }
  }
  return 0;
}

// Bundles of those frames (one frame each, and runs of them), behind the mode bytes of
// fuzz_frame_bundle.cpp.
int bundle_seeds(const std::string& dir) {
  int n = 0;
  const auto frames = seed_frames();
  for (std::size_t first = 0; first < frames.size(); first += 3) {
    dp::BundleEncoder enc;
    for (std::size_t i = first; i < frames.size() && i < first + 1 + first % 5; ++i)
      if (!enc.add(frames[i].bytes)) return 1;
    std::vector<std::uint8_t> bundle;
    if (!enc.finish(bundle)) return 1;
    for (const std::uint8_t mode : {0, 1, 3}) {
      std::vector<std::uint8_t> input{mode};
      input.insert(input.end(), bundle.begin(), bundle.end());
      if (!write(dir, n++, input.data(), input.size())) return 1;
    }
  }
  return 0;
}

}  // namespace

// A cell diff (a refinement with its children painted) and an undo history holding it, each
// behind its mode byte (fuzz_undo.cpp).
int undo_seeds(const std::string& dir) {
  namespace sc = deepcanvas::server_core;
  sc::CellDiffRecorder rec;
  const sc::CellCoord k{3, 5, 6, 7};
  rec.refine(1, k, 0xFF102030u, 0xFF102030u, 8);
  for (std::uint32_t i = 0; i < 8; i += 3)
    rec.colour(8 + i, {4, 10 + (i & 1), 12 + ((i >> 1) & 1), 14 + (i >> 2)}, true, 0xFF102030u,
               0x80A0B0C0u + i);
  const auto diff = sc::encode_cell_diff(rec.take());
  std::vector<std::uint8_t> a{0};
  a.insert(a.end(), diff.begin(), diff.end());
  sc::UndoHistory h;
  h.stroke_done(7, 1, diff);
  h.stroke_done(7, 2, diff);
  h.moved(7, 2, false, diff);
  const auto saved = h.save();
  std::vector<std::uint8_t> b{1};
  b.insert(b.end(), saved.begin(), saved.end());
  sc::CellPaste paste;
  paste.cells = {
      {{3, 5, 6, 7}, 0xFF102030u}, {{4, 2, 2, 2}, 0x80A0B0C0u}, {{5, 60, 1, 9}, 0x01020304u}};
  sc::OctreeConfig canvas;
  canvas.max_depth = 12;
  if (!sc::normalise_cell_paste(paste, canvas)) return 1;
  const auto pasted = sc::encode_cell_paste(paste);
  std::vector<std::uint8_t> c{2};
  c.insert(c.end(), pasted.begin(), pasted.end());
  return write(dir, 0, a.data(), a.size()) && write(dir, 1, b.data(), b.size()) &&
                 write(dir, 2, c.data(), c.size())
             ? 0
             : 1;
}

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr,
                 "usage: protocol_fuzz_seeds messages|block_frame|frame_bundle|tokens|undo DIR\n");
    return 2;
  }
  const std::string kind = argv[1], dir = argv[2];
  int n = 0;
  if (kind == "messages") {
    for (const auto& m : messages()) {
      const std::string text = dp::encode_message(m);
      if (!write(dir, n++, text.data(), text.size())) return 1;
    }
    return 0;
  }
  if (kind == "block_frame") return block_seeds(dir);
  if (kind == "frame_bundle") return bundle_seeds(dir);
  if (kind == "tokens") {
    const std::string a = "# tokens\nmain painter p-1\nmain viewer v-2\r\n\nother\tpainter  p-1\n";
    const std::string b = "c painter x";
    return write(dir, 0, a.data(), a.size()) && write(dir, 1, b.data(), b.size()) ? 0 : 1;
  }
  if (kind == "undo") return undo_seeds(dir);
  std::fprintf(stderr, "protocol_fuzz_seeds: unknown kind '%s'\n", kind.c_str());
  return 2;
}
