// PNG writer round trips through libpng's reader (label unit).
#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "deepcanvas/client_gpu/png.hpp"

namespace deepcanvas::client_gpu {
namespace {

namespace fs = std::filesystem;

class Png : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("deepcanvas_png_test_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(Png, RoundTripsRandomImagesOfAwkwardSizes) {
  std::mt19937 rng(42);
  for (auto [w, h] : {std::pair{1u, 1u}, std::pair{3u, 5u}, std::pair{640u, 360u},
                      std::pair{1u, 777u}, std::pair{1023u, 2u}}) {
    RgbaImage img{w, h, std::vector<std::uint8_t>(4ull * w * h)};
    for (auto& b : img.pixels) b = static_cast<std::uint8_t>(rng());
    const fs::path path = dir_ / ("img_" + std::to_string(w) + "x" + std::to_string(h) + ".png");
    auto written = write_png(path, img);
    ASSERT_TRUE(written) << written.error().message;
    EXPECT_FALSE(fs::exists(path.string() + ".tmp"));
    // A real PNG on disk: the signature, then libpng reads back the identical pixels.
    std::ifstream f(path, std::ios::binary);
    char sig[8] = {};
    f.read(sig, 8);
    EXPECT_EQ(std::string(sig, 8), std::string("\x89PNG\r\n\x1a\n", 8));
    auto back = read_png(path);
    ASSERT_TRUE(back) << back.error().message;
    EXPECT_EQ(back->width, w);
    EXPECT_EQ(back->height, h);
    EXPECT_EQ(back->pixels, img.pixels);
  }
}

TEST_F(Png, OverwritesAnExistingFile) {
  const fs::path path = dir_ / "same.png";
  RgbaImage a{2, 2, std::vector<std::uint8_t>(16, 10)};
  RgbaImage b{4, 1, std::vector<std::uint8_t>(16, 200)};
  ASSERT_TRUE(write_png(path, a));
  ASSERT_TRUE(write_png(path, b));
  auto back = read_png(path);
  ASSERT_TRUE(back);
  EXPECT_EQ(back->width, 4u);
  EXPECT_EQ(back->pixels, b.pixels);
}

TEST_F(Png, RejectsBadArgumentsAndChangesNothing) {
  const fs::path path = dir_ / "bad.png";
  std::vector<std::uint8_t> px(4 * 6);
  auto zero = write_png(path, 0, 6, px);
  ASSERT_FALSE(zero);
  EXPECT_EQ(zero.error().code, Errc::invalid_argument);
  auto short_span = write_png(path, 2, 4, std::span(px).first(31));
  ASSERT_FALSE(short_span);
  EXPECT_EQ(short_span.error().code, Errc::invalid_argument);
  EXPECT_FALSE(fs::exists(path));
  auto no_dir = write_png(dir_ / "missing" / "x.png", 2, 3, px);
  ASSERT_FALSE(no_dir);
  EXPECT_EQ(no_dir.error().code, Errc::io_error);
  EXPECT_NE(no_dir.error().message.find("x.png"), std::string::npos);
}

TEST_F(Png, ReadingRejectsMissingAndCorruptFiles) {
  auto missing = read_png(dir_ / "nope.png");
  ASSERT_FALSE(missing);
  EXPECT_EQ(missing.error().code, Errc::not_found);
  const fs::path junk = dir_ / "junk.png";
  std::ofstream(junk, std::ios::binary) << "this is not a png at all";
  auto bad = read_png(junk);
  ASSERT_FALSE(bad);
  EXPECT_EQ(bad.error().code, Errc::malformed);
  // A valid PNG cut short.
  const fs::path good = dir_ / "good.png";
  RgbaImage img{64, 64, std::vector<std::uint8_t>(4 * 64 * 64)};
  std::mt19937 rng(1);
  for (auto& b : img.pixels) b = static_cast<std::uint8_t>(rng());
  ASSERT_TRUE(write_png(good, img));
  fs::resize_file(good, fs::file_size(good) / 2);
  auto cut = read_png(good);
  ASSERT_FALSE(cut);
  EXPECT_EQ(cut.error().code, Errc::malformed);
}

}  // namespace
}  // namespace deepcanvas::client_gpu
