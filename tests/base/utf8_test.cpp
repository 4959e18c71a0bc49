// valid_utf8 against a brute-force reference: the set of every scalar value's encoding (all
// code points but the surrogates, encoded by the textbook formula). UTF-8 is prefix-free, so a
// string is valid exactly when it splits greedily into members of that set.
#include <gtest/gtest.h>

#include <random>
#include <set>
#include <string>

#include "deepcanvas/base/utf8.hpp"

namespace {

using deepcanvas::base::valid_utf8;

std::string encode(char32_t cp) {
  std::string s;
  if (cp < 0x80) {
    s += static_cast<char>(cp);
  } else if (cp < 0x800) {
    s += static_cast<char>(0xc0 | (cp >> 6));
    s += static_cast<char>(0x80 | (cp & 0x3f));
  } else if (cp < 0x10000) {
    s += static_cast<char>(0xe0 | (cp >> 12));
    s += static_cast<char>(0x80 | ((cp >> 6) & 0x3f));
    s += static_cast<char>(0x80 | (cp & 0x3f));
  } else {
    s += static_cast<char>(0xf0 | (cp >> 18));
    s += static_cast<char>(0x80 | ((cp >> 12) & 0x3f));
    s += static_cast<char>(0x80 | ((cp >> 6) & 0x3f));
    s += static_cast<char>(0x80 | (cp & 0x3f));
  }
  return s;
}

const std::set<std::string>& encodings() {
  static const std::set<std::string> all = [] {
    std::set<std::string> s;
    for (char32_t cp = 0; cp <= 0x10ffff; ++cp)
      if (cp < 0xd800 || cp > 0xdfff) s.insert(encode(cp));
    return s;
  }();
  return all;
}

bool reference_valid(const std::string& s) {
  std::size_t i = 0;
  while (i < s.size()) {
    bool found = false;
    for (std::size_t n = 1; n <= 4 && i + n <= s.size() && !found; ++n)
      if (encodings().count(s.substr(i, n))) {
        i += n;
        found = true;
      }
    if (!found) return false;
  }
  return true;
}

TEST(Utf8, EverySequenceOfUpToThreeBytesMatchesTheReference) {
  // All 1- and 2-byte strings, and 3-byte strings over the bytes that matter at each position.
  std::string s;
  for (int a = 0; a < 256; ++a) {
    s.assign(1, static_cast<char>(a));
    ASSERT_EQ(valid_utf8(s), reference_valid(s)) << a;
    for (int b = 0; b < 256; ++b) {
      s.assign({static_cast<char>(a), static_cast<char>(b)});
      ASSERT_EQ(valid_utf8(s), reference_valid(s)) << a << " " << b;
    }
  }
  for (int a = 0xc0; a < 256; ++a)
    for (int b = 0x70; b < 0xd0; ++b)
      for (int c = 0x70; c < 0xd0; c += 3) {
        s.assign({static_cast<char>(a), static_cast<char>(b), static_cast<char>(c)});
        ASSERT_EQ(valid_utf8(s), reference_valid(s)) << a << " " << b << " " << c;
      }
}

TEST(Utf8, RandomStringsMatchTheReference) {
  std::mt19937 rng(11);
  std::uniform_int_distribution<int> len(0, 24), byte(0, 255), pick(0, 3);
  std::uniform_int_distribution<std::uint32_t> cp(0, 0x10ffff);
  int valid = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    // Mostly whole characters with now and then a random byte, so both outcomes are common.
    std::string s;
    for (int k = len(rng); k > 0; --k) {
      if (pick(rng) == 0) {
        s += static_cast<char>(byte(rng));
      } else {
        const char32_t c = cp(rng);
        if (c < 0xd800 || c > 0xdfff) s += encode(c);
      }
    }
    const bool ref = reference_valid(s);
    valid += ref;
    ASSERT_EQ(valid_utf8(s), ref) << trial;
  }
  EXPECT_GT(valid, 2000);
  EXPECT_LT(valid, 18000);
}

TEST(Utf8, NamedCases) {
  EXPECT_TRUE(valid_utf8(""));
  EXPECT_TRUE(valid_utf8("{\"type\":\"hello\"} caf\xc3\xa9 \xf0\x9f\x8e\xa8"));
  EXPECT_FALSE(valid_utf8("\xc0\xaf"));          // overlong '/'
  EXPECT_FALSE(valid_utf8("\xed\xa0\x80"));      // a surrogate
  EXPECT_FALSE(valid_utf8("\xf4\x90\x80\x80"));  // above U+10FFFF
  EXPECT_FALSE(valid_utf8("abc\xe2\x82"));       // cut off
}

}  // namespace
