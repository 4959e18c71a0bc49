// pool_hash: the hash that says two copies of a canvas's pools are byte-identical.
//
// The server (server_core::Octree::pool_hash) and every replica (client_core::Replica) must
// compute exactly this: the high-water mark in groups, then the first_child and colour pools
// (4 bytes per cell), the group parent pool (4 bytes per group) and the depth_flags pool (1 byte
// per group), each up to the high-water mark, little-endian. Links are excluded: they are
// derived data that each replica computes itself.
//
// The hash is a 64-bit streaming multiply-rotate hash over 64-bit words (murmur-style) with a
// final avalanche: not cryptographic, fast (several GB/s). Host byte order must be
// little-endian (the pools are hashed as they lie in memory).
//
// Threading: pure functions.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>

namespace deepcanvas::protocol {

class PoolHasher {
 public:
  void add(std::uint64_t v) noexcept {
    v *= 0x87c37b91114253d5ull;
    v = (v << 31) | (v >> 33);
    v *= 0x4cf5ad432745937full;
    h_ ^= v;
    h_ = (h_ << 27) | (h_ >> 37);
    h_ = h_ * 5 + 0x52dce729;
  }
  void add_bytes(const void* data, std::size_t n) noexcept {
    const auto* p = static_cast<const unsigned char*>(data);
    std::size_t i = 0;
    for (; i + 8 <= n; i += 8) {
      std::uint64_t w;
      std::memcpy(&w, p + i, 8);
      add(w);
    }
    if (i < n) {
      std::uint64_t w = 0;
      std::memcpy(&w, p + i, n - i);
      add(w ^ (std::uint64_t{n - i} << 56));
    }
    add(n);
  }
  std::uint64_t finish() const noexcept {
    std::uint64_t k = h_;
    k ^= k >> 33;
    k *= 0xff51afd7ed558ccdull;
    k ^= k >> 33;
    k *= 0xc4ceb9fe1a85ec53ull;
    k ^= k >> 33;
    return k;
  }

 private:
  std::uint64_t h_ = 0x9e3779b97f4a7c15ull;
};

// The pools hold exactly high-water cells (first_child, colour) and groups (parent, depth).
inline std::uint64_t pool_hash(std::uint64_t hw_groups, std::span<const std::uint32_t> first_child,
                               std::span<const std::uint32_t> colour,
                               std::span<const std::uint32_t> group_parent,
                               std::span<const std::uint8_t> depth_flags) noexcept {
  PoolHasher h;
  h.add(hw_groups);
  h.add_bytes(first_child.data(), hw_groups * 8 * 4);
  h.add_bytes(colour.data(), hw_groups * 8 * 4);
  h.add_bytes(group_parent.data(), hw_groups * 4);
  h.add_bytes(depth_flags.data(), hw_groups);
  return h.finish();
}

}  // namespace deepcanvas::protocol
