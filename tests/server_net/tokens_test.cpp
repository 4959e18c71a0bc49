// Tokens file: the format, line-numbered errors that never echo a token, authorization rules.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <random>
#include <string>

#include "deepcanvas/server_net/tokens.hpp"

namespace dp = deepcanvas::protocol;
using deepcanvas::Errc;

TEST(Tokens, ParsesEntriesCommentsBlanksTabsAndCrlf) {
  const std::string text =
      "# deepcanvas tokens\n"
      "\n"
      "main painter p-secret-1\r\n"
      "   main\tviewer   v-secret-2  \n"
      "  # indented comment\n"
      "other.canvas_2 painter p-other\n"
      "main painter p-secret-3";  // no final newline
  auto t = deepcanvas::server_net::TokenTable::parse(text);
  ASSERT_TRUE(t.ok()) << t.error().message;
  ASSERT_EQ(t->entries().size(), 4u);
  EXPECT_EQ(t->entries()[0].canvas, "main");
  EXPECT_EQ(t->entries()[0].role, dp::Role::painter);
  EXPECT_EQ(t->entries()[0].token, "p-secret-1");
  EXPECT_EQ(t->entries()[1].role, dp::Role::viewer);
  EXPECT_EQ(t->entries()[1].token, "v-secret-2");
  EXPECT_EQ(t->entries()[3].token, "p-secret-3");
  EXPECT_EQ(t->canvases(), (std::vector<std::string>{"main", "other.canvas_2"}));
  EXPECT_TRUE(deepcanvas::server_net::TokenTable::parse("").ok());
}

TEST(Tokens, BadLinesAreNamedAndTokensNeverEchoed) {
  const struct {
    std::string text;
    std::string expect;
  } cases[] = {
      {"main painter\n", "line 1"},
      {"# ok\nmain painter tok extra\n", "line 2"},
      {"main admin topsecret\n", "role"},
      {"bad/name painter topsecret\n", "canvas"},
      {"main painter top\x01secret\n", "control"},
      {"main painter top\xc3\xa9secret\n", "non-ASCII"},
      {"main painter topsecret\nmain viewer topsecret\n", "duplicate"},
      {"main painter " + std::string(257, 'x') + "\n", "token"},
  };
  for (const auto& c : cases) {
    auto t = deepcanvas::server_net::TokenTable::parse(c.text);
    ASSERT_FALSE(t.ok()) << c.text;
    EXPECT_EQ(t.error().code, Errc::malformed);
    EXPECT_NE(t.error().message.find(c.expect), std::string::npos) << t.error().message;
    EXPECT_EQ(t.error().message.find("topsecret"), std::string::npos) << t.error().message;
  }
  // The same token on two canvases is fine.
  EXPECT_TRUE(deepcanvas::server_net::TokenTable::parse("a painter t\nb painter t\n").ok());
  EXPECT_EQ(deepcanvas::server_net::TokenTable::parse(std::string(deepcanvas::server_net::TokenTable::kMaxFileBytes + 1, '#')).error().code,
            Errc::limit_exceeded);
}

TEST(Tokens, Authorize) {
  auto t = deepcanvas::server_net::TokenTable::parse("main painter pp\nmain viewer vv\nother viewer pp\n");
  ASSERT_TRUE(t.ok());
  const auto role = [&](std::string_view canvas, std::string_view token, dp::Role want) {
    auto r = t->authorize(canvas, token, want);
    return r.ok() ? std::string(dp::role_name(*r))
                  : std::string(deepcanvas::errc_name(r.error().code));
  };
  EXPECT_EQ(role("main", "pp", dp::Role::painter), "painter");
  EXPECT_EQ(role("main", "pp", dp::Role::viewer), "viewer");
  EXPECT_EQ(role("main", "vv", dp::Role::viewer), "viewer");
  EXPECT_EQ(role("main", "vv", dp::Role::painter), "unauthorized");
  EXPECT_EQ(role("other", "pp", dp::Role::painter), "unauthorized");  // viewer there
  EXPECT_EQ(role("other", "pp", dp::Role::viewer), "viewer");
  EXPECT_EQ(role("main", "p", dp::Role::viewer), "unauthorized");
  EXPECT_EQ(role("main", "ppp", dp::Role::viewer), "unauthorized");
  EXPECT_EQ(role("main", "", dp::Role::viewer), "unauthorized");
  EXPECT_EQ(role("nowhere", "pp", dp::Role::viewer), "unauthorized");
}

TEST(Tokens, LoadFromFile) {
  const std::string path = ::testing::TempDir() + "deepcanvas_tokens_test.txt";
  {
    std::ofstream out(path, std::ios::binary);
    out << "main painter abc\n";
  }
  auto t = deepcanvas::server_net::TokenTable::load(path);
  ASSERT_TRUE(t.ok()) << t.error().message;
  EXPECT_EQ(t->entries().size(), 1u);
  {
    std::ofstream out(path, std::ios::binary);
    out << "main painter\n";
  }
  auto bad = deepcanvas::server_net::TokenTable::load(path);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find(path), std::string::npos);
  std::remove(path.c_str());
  auto missing = deepcanvas::server_net::TokenTable::load(path);
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, Errc::not_found);
}

TEST(Tokens, RandomBytesNeverCrashAndAcceptedTablesAreValid) {
  std::mt19937_64 rng(21);
  const std::string alphabet = "ab .-_#\t\r\npainterviewer\x01\xff";
  for (int i = 0; i < 3000; ++i) {
    std::string s(rng() % 80, ' ');
    for (auto& c : s) c = alphabet[rng() % alphabet.size()];
    auto t = deepcanvas::server_net::TokenTable::parse(s);
    if (!t.ok()) continue;
    for (const auto& e : t->entries()) {
      EXPECT_TRUE(dp::is_valid_canvas_name(e.canvas));
      EXPECT_TRUE(dp::is_valid_token(e.token));
    }
  }
}
