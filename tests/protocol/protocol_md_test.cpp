// PROTOCOL.md is a contract: the block decoder of its example client
// (protocol/examples/minimal_client.py), run as it is, must decode frames made by the C++ encoder
// (every flag combination, every field, a mask-only frame, index edge cases) to the same pools.
// The document's own checks (excerpts, section references) and the example against a real server
// are the ctests protocol_doc_lint and protocol_example_client (tests/protocol/CMakeLists.txt).
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <vector>

#include "deepcanvas/protocol/block_frame.hpp"

namespace dp = deepcanvas::protocol;
namespace fs = std::filesystem;

TEST(ProtocolMd, PythonDecoderMatchesTheEncoder) {
  if (std::system("python3 -c 'import sys' >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "python3 is not installed";
  const bool have_zstd = std::system("python3 -c 'import zstandard' >/dev/null 2>&1") == 0 ||
                         std::system("zstd --version >/dev/null 2>&1") == 0;
  const fs::path dir = fs::path(::testing::TempDir()) / "deepcanvas_protocol_md";
  fs::remove_all(dir);
  fs::create_directories(dir);

  std::mt19937_64 rng(31);
  struct Case {
    std::vector<std::uint32_t> fc, colour, gp;
    std::vector<std::uint8_t> df;
    std::vector<std::uint64_t> mask;
    dp::BlockView view;
  };
  std::vector<Case> cases;
  const dp::BlockEncodeOptions options[] = {
      {1, true, true}, {1, false, true}, {1, true, false}, {1, false, false}};
  for (int i = 0; i < 8; ++i) {
    const auto& opt = options[i % 4];
    if (opt.compress && !have_zstd) continue;
    Case c;
    const std::uint32_t cells = 8 * (1 + static_cast<std::uint32_t>(rng() % 40));
    std::uint32_t last = 0;
    for (std::uint32_t k = 0; k < cells; ++k) {
      const std::uint32_t pick = static_cast<std::uint32_t>(rng() % 5);
      const std::uint32_t v = pick == 0   ? dp::kNoCellWire
                              : pick == 1 ? last + 8
                              : pick == 2 ? last + 8 + 0x80000000u
                              : pick == 3 ? dp::kNoCellWire - 1
                                          : static_cast<std::uint32_t>(rng());
      if (v != dp::kNoCellWire) last = v;
      c.fc.push_back(v);
      c.colour.push_back(static_cast<std::uint32_t>(rng()));
    }
    for (std::uint32_t g = 0; g < cells / 8; ++g) {
      c.gp.push_back(g % 3 ? static_cast<std::uint32_t>(rng()) : dp::kNoCellWire);
      c.df.push_back(static_cast<std::uint8_t>(rng()));
    }
    c.mask.assign((cells / 8 + 63) / 64, rng());
    cases.push_back(std::move(c));
    Case& k = cases.back();
    k.view.block_id = static_cast<std::uint32_t>(i);
    k.view.version = rng() >> 1;
    k.view.epoch = rng() >> 1;
    k.view.first_cell = 8 * static_cast<std::uint32_t>(rng() % 1000);
    k.view.cell_count = cells;
    // Frame 5 lacks some pools, frame 6 the mask; frame 7 is a mask-only frame (fields 0x10,
    // neither compressed nor transformed, as the server sends them).
    if (i != 5 && i != 7) k.view.first_child = k.fc;
    if (i != 7) k.view.colour = k.colour;
    if (i != 5 && i != 7) k.view.group_parent = k.gp;
    if (i != 7) k.view.depth_flags = k.df;
    if (i != 6) k.view.neighbour_mask = k.mask;
    dp::BlockEncoder enc(opt);
    auto frame = enc.encode(k.view);
    ASSERT_TRUE(frame.ok());
    std::ofstream(dir / ("f" + std::to_string(cases.size() - 1) + ".frame"), std::ios::binary)
        .write(reinterpret_cast<const char*>(frame->data()),
               static_cast<std::streamsize>(frame->size()));
  }
  const std::string cmd = std::string("python3 ") + DEEPCANVAS_PROTOCOL_MD_CHECK + " decode " +
                          DEEPCANVAS_PROTOCOL_EXAMPLE + " " + dir.string();
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;

  dp::BlockDecoder dec;
  for (std::size_t i = 0; i < cases.size(); ++i) {
    std::ifstream in(dir / ("f" + std::to_string(i) + ".json"));
    ASSERT_TRUE(in) << "no output for frame " << i;
    const auto j = nlohmann::json::parse(in);
    const auto& v = cases[i].view;
    EXPECT_EQ(j["epoch"].get<std::uint64_t>(), v.epoch);
    EXPECT_EQ(j["block"].get<std::uint32_t>(), v.block_id);
    EXPECT_EQ(j["version"].get<std::uint64_t>(), v.version);
    EXPECT_EQ(j["first"].get<std::uint32_t>(), v.first_cell);
    EXPECT_EQ(j["cells"].get<std::uint32_t>(), v.cell_count);
    const auto pool = [&](const char* k) {
      return j.contains(k) ? j[k].get<std::vector<std::uint32_t>>() : std::vector<std::uint32_t>{};
    };
    EXPECT_EQ(pool("first_child"),
              std::vector<std::uint32_t>(v.first_child.begin(), v.first_child.end()));
    EXPECT_EQ(pool("colour"), std::vector<std::uint32_t>(v.colour.begin(), v.colour.end()));
    EXPECT_EQ(pool("group_parent"),
              std::vector<std::uint32_t>(v.group_parent.begin(), v.group_parent.end()));
    EXPECT_EQ(pool("depth_flags"),
              std::vector<std::uint32_t>(v.depth_flags.begin(), v.depth_flags.end()));
    if (!v.neighbour_mask.empty()) {
      const auto bytes = pool("mask");
      const std::uint32_t groups = v.cell_count / 8;
      ASSERT_EQ(bytes.size(), (groups + 7) / 8);
      for (std::uint32_t g = 0; g < groups; ++g)
        EXPECT_EQ((bytes[g / 8] >> (g % 8)) & 1, (v.neighbour_mask[g / 64] >> (g % 64)) & 1);
    }
  }
  fs::remove_all(dir);
}
