#include "deepcanvas/client_gpu/png.hpp"

#include <png.h>

#include <cstring>
#include <string>
#include <system_error>

namespace deepcanvas::client_gpu {

namespace {
constexpr std::uint32_t kMaxSide = 1u << 24;
constexpr std::uint64_t kMaxPixels = 1ull << 28;
}  // namespace

Result<void> write_png(const std::filesystem::path& path, std::uint32_t width, std::uint32_t height,
                       std::span<const std::uint8_t> rgba) {
  if (width == 0 || height == 0 || width > kMaxSide || height > kMaxSide) {
    return make_error(Errc::invalid_argument,
                      "PNG size " + std::to_string(width) + "x" + std::to_string(height) +
                          " (each side must be 1.." + std::to_string(kMaxSide) + ")");
  }
  const std::uint64_t bytes = 4ull * width * height;
  if (rgba.size() != bytes) {
    return make_error(Errc::invalid_argument, "PNG pixels: " + std::to_string(rgba.size()) +
                                                  " bytes for " + std::to_string(width) + "x" +
                                                  std::to_string(height) + " RGBA (need " +
                                                  std::to_string(bytes) + ")");
  }
  // The simplified libpng API reports errors through return codes (no setjmp in our code).
  png_image image;
  std::memset(&image, 0, sizeof(image));
  image.version = PNG_IMAGE_VERSION;
  image.width = width;
  image.height = height;
  image.format = PNG_FORMAT_RGBA;
  std::filesystem::path tmp = path;
  tmp += ".tmp";
  const std::string tmp_name = tmp.string();
  if (png_image_write_to_file(&image, tmp_name.c_str(), 0, rgba.data(),
                              static_cast<png_int_32>(4 * width), nullptr) == 0) {
    std::string why = image.message;
    png_image_free(&image);
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    return make_error(Errc::io_error, "cannot write PNG '" + path.string() + "': " + why);
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    return make_error(Errc::io_error, "cannot rename '" + tmp_name + "' to '" + path.string() +
                                          "': " + ec.message());
  }
  return {};
}

Result<RgbaImage> read_png(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    return make_error(Errc::not_found, "no PNG file '" + path.string() + "'");
  }
  png_image image;
  std::memset(&image, 0, sizeof(image));
  image.version = PNG_IMAGE_VERSION;
  const std::string name = path.string();
  if (png_image_begin_read_from_file(&image, name.c_str()) == 0) {
    std::string why = image.message;
    png_image_free(&image);
    return make_error(Errc::malformed, "'" + name + "' is not a readable PNG: " + why);
  }
  if (static_cast<std::uint64_t>(image.width) * image.height > kMaxPixels) {
    png_image_free(&image);
    return make_error(Errc::limit_exceeded, "'" + name + "': " + std::to_string(image.width) + "x" +
                                                std::to_string(image.height) +
                                                " exceeds the 2^28 pixel limit");
  }
  image.format = PNG_FORMAT_RGBA;
  RgbaImage out;
  out.width = image.width;
  out.height = image.height;
  out.pixels.resize(PNG_IMAGE_SIZE(image));
  if (png_image_finish_read(&image, nullptr, out.pixels.data(), 0, nullptr) == 0) {
    std::string why = image.message;
    png_image_free(&image);
    return make_error(Errc::malformed, "'" + name + "': PNG decoding failed: " + why);
  }
  return out;
}

Result<void> write_frame_png(const std::filesystem::path& path, std::uint32_t width,
                             std::uint32_t height, std::span<const std::uint32_t> words) {
  if (words.size() != std::size_t{width} * height)
    return make_error(Errc::invalid_argument, "write_frame_png: the pixels are not width x height");
  std::vector<std::uint8_t> rgba(words.size() * 4);
  for (std::size_t i = 0; i < words.size(); ++i) {
    const std::uint32_t v = words[i];
    rgba[i * 4 + 0] = static_cast<std::uint8_t>(v);
    rgba[i * 4 + 1] = static_cast<std::uint8_t>(v >> 8);
    rgba[i * 4 + 2] = static_cast<std::uint8_t>(v >> 16);
    rgba[i * 4 + 3] = 255;
  }
  return write_png(path, width, height, rgba);
}

}  // namespace deepcanvas::client_gpu
