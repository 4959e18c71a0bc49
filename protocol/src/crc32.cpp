// CRC-32 (reflected polynomial 0xEDB88320): a slicing-by-8 table version for every CPU, and on
// x86-64 CPUs with PCLMULQDQ the folding method of Gopal et al., "Fast CRC Computation for
// Generic Polynomials Using PCLMULQDQ Instruction" (Intel, 2009): four 128-bit lanes are folded
// forward 512 bits at a time by carry-less multiplication with x^(512+-32..) mod P constants,
// reduced to one lane, to 64 and 32 bits, then Barrett-reduced. The constants below are those
// powers of x modulo P in the bit-reflected domain (they follow from P alone).
#include <cstring>

#include "deepcanvas/protocol/block_frame.hpp"

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define DEEPCANVAS_CRC32_CLMUL 1
#endif

namespace deepcanvas::protocol {
namespace {

struct CrcTables {
  std::uint32_t t[8][256];
  CrcTables() {
    for (std::uint32_t i = 0; i < 256; ++i) {
      std::uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      t[0][i] = c;
    }
    for (std::uint32_t i = 0; i < 256; ++i)
      for (int s = 1; s < 8; ++s) t[s][i] = (t[s - 1][i] >> 8) ^ t[0][t[s - 1][i] & 0xFF];
  }
};
const CrcTables& crc_tables() {
  static const CrcTables tables;
  return tables;
}

std::uint32_t load32(const std::uint8_t* p) {
  std::uint32_t v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

// The register form (pre- and post-inversion left to the caller).
std::uint32_t crc_table_raw(const std::uint8_t* p, std::size_t n, std::uint32_t c) {
  const auto& t = crc_tables().t;
  while (n >= 8) {
    const std::uint32_t lo = load32(p) ^ c;
    const std::uint32_t hi = load32(p + 4);
    c = t[7][lo & 0xFF] ^ t[6][(lo >> 8) & 0xFF] ^ t[5][(lo >> 16) & 0xFF] ^ t[4][lo >> 24] ^
        t[3][hi & 0xFF] ^ t[2][(hi >> 8) & 0xFF] ^ t[1][(hi >> 16) & 0xFF] ^ t[0][hi >> 24];
    p += 8;
    n -= 8;
  }
  while (n--) c = t[0][(c ^ *p++) & 0xFF] ^ (c >> 8);
  return c;
}

#ifdef DEEPCANVAS_CRC32_CLMUL
// a.lo * k.lo ^ a.hi * k.hi ^ next: lane `a` moved forward onto `next`.
__attribute__((target("pclmul,sse4.1"))) inline __m128i fold(__m128i a, __m128i k, __m128i next) {
  return _mm_xor_si128(
      _mm_xor_si128(_mm_clmulepi64_si128(a, k, 0x00), _mm_clmulepi64_si128(a, k, 0x11)), next);
}

// Folds `n` bytes (n >= 64, a multiple of 16) into the register `c`.
__attribute__((target("pclmul,sse4.1"))) std::uint32_t crc_clmul_raw(const std::uint8_t* p,
                                                                     std::size_t n,
                                                                     std::uint32_t c) {
  // (x^(4*128+32) mod P, x^(4*128-32) mod P): one lane folded 512 bits forward.
  const __m128i fold4 = _mm_set_epi64x(0x1c6e41596, 0x154442bd4);
  // The same for 128 bits: one lane into the next.
  const __m128i fold1 = _mm_set_epi64x(0x0ccaa009e, 0x1751997d0);
  const __m128i fold64 = _mm_set_epi64x(0, 0x163cd6124);  // 64 -> 32 bits
  // Barrett: P' (the polynomial with its x^32 term) and mu = floor(x^64 / P), reflected.
  const __m128i barrett = _mm_set_epi64x(0x1f7011641, 0x1db710641);
  const __m128i low32 = _mm_setr_epi32(-1, 0, -1, 0);
  const auto load = [](const std::uint8_t* q) {
    return _mm_loadu_si128(reinterpret_cast<const __m128i*>(q));
  };
  __m128i l0 = _mm_xor_si128(load(p), _mm_cvtsi32_si128(static_cast<int>(c)));
  __m128i l1 = load(p + 16), l2 = load(p + 32), l3 = load(p + 48);
  p += 64;
  n -= 64;
  for (; n >= 64; p += 64, n -= 64) {
    l0 = fold(l0, fold4, load(p));
    l1 = fold(l1, fold4, load(p + 16));
    l2 = fold(l2, fold4, load(p + 32));
    l3 = fold(l3, fold4, load(p + 48));
  }
  __m128i x = fold(fold(fold(l0, fold1, l1), fold1, l2), fold1, l3);
  for (; n >= 16; p += 16, n -= 16) x = fold(x, fold1, load(p));
  // 128 -> 64 bits: the low half times x^(128-32..) onto the high half.
  x = _mm_xor_si128(_mm_srli_si128(x, 8), _mm_clmulepi64_si128(x, fold1, 0x10));
  // 64 -> 32 (+32) bits.
  x = _mm_xor_si128(_mm_clmulepi64_si128(_mm_and_si128(x, low32), fold64, 0x00),
                    _mm_srli_si128(x, 4));
  // Barrett reduction to the 32-bit remainder (in the second dword).
  __m128i t = _mm_clmulepi64_si128(_mm_and_si128(x, low32), barrett, 0x10);
  t = _mm_clmulepi64_si128(_mm_and_si128(t, low32), barrett, 0x00);
  return static_cast<std::uint32_t>(_mm_extract_epi32(_mm_xor_si128(x, t), 1));
}

bool have_clmul() {
  static const bool yes = __builtin_cpu_supports("pclmul") && __builtin_cpu_supports("sse4.1");
  return yes;
}
#endif

}  // namespace

std::uint32_t crc32_portable(std::span<const std::uint8_t> bytes, std::uint32_t crc) noexcept {
  return ~crc_table_raw(bytes.data(), bytes.size(), ~crc);
}

std::uint32_t crc32(std::span<const std::uint8_t> bytes, std::uint32_t crc) noexcept {
  std::uint32_t c = ~crc;
  const std::uint8_t* p = bytes.data();
  std::size_t n = bytes.size();
#ifdef DEEPCANVAS_CRC32_CLMUL
  if (n >= 64 && have_clmul()) {
    const std::size_t folded = n & ~std::size_t{15};
    c = crc_clmul_raw(p, folded, c);
    p += folded;
    n -= folded;
  }
#endif
  return ~crc_table_raw(p, n, c);
}

}  // namespace deepcanvas::protocol
