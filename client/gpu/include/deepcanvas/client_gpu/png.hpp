// PNG files for rendered frames (libpng; no Vulkan involved: it lives here until client_core
// wants it). 8-bit RGBA, rows top to bottom, tightly packed (stride = 4 * width).
// Thread-safe: no shared state. Files are written to "<path>.tmp" then renamed, so a reader
// never sees half a PNG.
#pragma once

#include <cstdint>
#include <filesystem>
#include <span>
#include <vector>

#include "deepcanvas/base/result.hpp"

namespace deepcanvas::client_gpu {

struct RgbaImage {
  std::uint32_t width = 0;
  std::uint32_t height = 0;
  std::vector<std::uint8_t> pixels;  // 4 * width * height bytes, RGBA
};

// Errors: invalid_argument (zero size, dimensions over 2^24 per side, or pixel span not
// 4*w*h bytes), io_error (cannot write or rename; the message names the path and libpng's or
// the OS's reason).
Result<void> write_png(const std::filesystem::path& path, std::uint32_t width, std::uint32_t height,
                       std::span<const std::uint8_t> rgba);
inline Result<void> write_png(const std::filesystem::path& path, const RgbaImage& image) {
  return write_png(path, image.width, image.height, image.pixels);
}

// A frame of the ray caster (RGBA8 words, r in the low byte: GpuRaycaster / RenderLoop
// read_pixels()) as a PNG, stored opaque: its colour is composited over the background
// already. invalid_argument when `words` is not width * height; else as write_png.
Result<void> write_frame_png(const std::filesystem::path& path, std::uint32_t width,
                             std::uint32_t height, std::span<const std::uint32_t> words);

// Reads any PNG libpng understands, converted to 8-bit RGBA. Untrusted input: errors
// not_found, malformed (libpng's message), limit_exceeded (over 2^28 pixels).
Result<RgbaImage> read_png(const std::filesystem::path& path);

}  // namespace deepcanvas::client_gpu
