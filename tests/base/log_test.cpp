#include "deepcanvas/base/log.hpp"

#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>

#include <nlohmann/json.hpp>

#include <chrono>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace {

using namespace deepcanvas::base;

// Routes the logger into a string for one test and restores stderr and the defaults after.
class LogTest : public ::testing::Test {
 protected:
  void SetUp() override {
    set_log_sink(std::make_shared<spdlog::sinks::ostream_sink_mt>(out_));
    set_log_level(LogLevel::debug);
    set_log_format(LogFormat::text);
    set_log_rate_limit(0);
  }
  void TearDown() override {
    set_log_sink(nullptr);
    set_log_level(LogLevel::info);
    set_log_format(LogFormat::text);
    set_log_rate_limit(20);
  }
  std::vector<std::string> lines() const {
    std::vector<std::string> v;
    std::istringstream in(out_.str());
    for (std::string l; std::getline(in, l);) v.push_back(l);
    return v;
  }
  void clear() {
    out_.str("");
    out_.clear();
  }
  std::ostringstream out_;
};

std::string random_bytes(std::mt19937& rng) {
  std::uniform_int_distribution<int> len(0, 24), byte(0, 255), pick(0, 3);
  std::string s(static_cast<std::size_t>(len(rng)), '\0');
  for (char& c : s) {
    // Bias towards the bytes that matter: controls, quotes, backslash, '=', space, high bytes.
    static constexpr char kSpecial[] = {'\0', '\x1b', '\r', '\n', '"', '\\', '=', ' ', '\x7f',
                                        '\xc2', '\x9b', '\xe2', '\x82'};
    c = pick(rng) == 0 ? kSpecial[static_cast<std::size_t>(byte(rng)) % sizeof kSpecial]
                       : static_cast<char>(byte(rng));
  }
  return s;
}

std::string random_utf8(std::mt19937& rng) {
  static const std::vector<std::string> kPieces = {"a", "Z", " ", "=", "\"", "\\", "\n", "\r",
                                                   std::string(1, '\0'), "\x1b[2J", "\x7f",
                                                   "\xc3\xa9", "\xe2\x82\xac", "\xf0\x9f\x8e\xa8",
                                                   "\xc2\x9b"};
  std::uniform_int_distribution<std::size_t> len(0, 12), pick(0, kPieces.size() - 1);
  std::string s;
  for (std::size_t n = len(rng); n > 0; --n) s += kPieces[pick(rng)];
  return s;
}

TEST_F(LogTest, TextLineHasNoRawControlBytesForAnyValue) {
  std::mt19937 rng(1234);
  for (int i = 0; i < 3000; ++i) {
    clear();
    const std::string value = random_bytes(rng);
    log_event(LogLevel::info, "hello", {{"client_name", value}, {"n", i}});
    const std::string text = out_.str();
    ASSERT_FALSE(text.empty());
    ASSERT_EQ(text.back(), '\n');
    std::size_t newlines = 0;
    for (std::size_t k = 0; k < text.size(); ++k) {
      const auto c = static_cast<unsigned char>(text[k]);
      if (c == '\n') ++newlines;
      ASSERT_TRUE(c == '\n' || (c >= 0x20 && c != 0x7f)) << "raw byte " << int(c) << " in " << text;
      // A C1 CSI (U+009B) would act on a terminal as ESC [ does.
      if (c == 0xc2 && k + 1 < text.size()) {
        ASSERT_GE(static_cast<unsigned char>(text[k + 1]), 0xa0) << text;
      }
    }
    ASSERT_EQ(newlines, 1u) << text;
    // The value cannot forge a field: the line still ends with the n= field we wrote last.
    ASSERT_NE(text.find(" n=" + std::to_string(i) + "\n"), std::string::npos) << text;
  }
}

TEST_F(LogTest, TextQuotesAndEscapes) {
  log_event(LogLevel::info, "e", {{"a", "plain"}, {"b", "two words"}, {"c", "x\"y\\z"},
                                  {"d", std::string_view("\x1b\r\0", 3)}, {"e", ""}});
  const auto l = lines();
  ASSERT_EQ(l.size(), 1u);
  EXPECT_NE(l[0].find(" level=info event=e a=plain b=\"two words\" c=\"x\\\"y\\\\z\" "
                      "d=\"\\x1b\\r\\x00\" e=\"\""),
            std::string::npos)
      << l[0];
  EXPECT_EQ(l[0].rfind("ts=", 0), 0u) << l[0];
}

TEST_F(LogTest, JsonLineParsesForAnyBytesAndGivesValidUtf8Back) {
  set_log_format(LogFormat::json);
  std::mt19937 rng(99);
  for (int i = 0; i < 3000; ++i) {
    clear();
    const bool utf8 = i % 2 == 0;
    const std::string value = utf8 ? random_utf8(rng) : random_bytes(rng);
    log_event(LogLevel::warn, "hello", {{"client_name", value}, {"n", i}, {"ratio", 0.5}});
    const std::string text = out_.str();
    ASSERT_EQ(text.back(), '\n');
    ASSERT_EQ(text.find('\n'), text.size() - 1) << text;
    nlohmann::json j;
    ASSERT_NO_THROW(j = nlohmann::json::parse(text)) << text;
    ASSERT_TRUE(j.is_object());
    EXPECT_EQ(j["level"], "warn");
    EXPECT_EQ(j["event"], "hello");
    EXPECT_EQ(j["n"], i);
    EXPECT_DOUBLE_EQ(j["ratio"].get<double>(), 0.5);
    ASSERT_TRUE(j["client_name"].is_string());
    if (utf8) {
      EXPECT_EQ(j["client_name"].get<std::string>(), value) << text;
    }
  }
}

TEST_F(LogTest, JsonInvalidUtf8IsEscaped) {
  set_log_format(LogFormat::json);
  log_event(LogLevel::info, "e", {{"v", std::string_view("a\xff\xc3", 3)}});
  const auto j = nlohmann::json::parse(out_.str());
  EXPECT_EQ(j["v"], "a\\xff\\xc3");
}

// C1 controls (U+0080..U+009F) act on terminals like ESC: never raw in either format. Text
// escapes their bytes; JSON escapes the code point, which parses back to the same string.
TEST_F(LogTest, C1ControlsAreEscapedInBothFormats) {
  const std::string_view csi("x\xc2\x9b" "2J", 5);
  log_event(LogLevel::info, "e", {{"v", csi}});
  EXPECT_NE(out_.str().find("v=\"x\\xc2\\x9b2J\""), std::string::npos) << out_.str();
  clear();
  set_log_format(LogFormat::json);
  log_event(LogLevel::info, "e", {{"v", csi}});
  EXPECT_NE(out_.str().find("\"v\":\"x\\u009b2J\""), std::string::npos) << out_.str();
  EXPECT_EQ(nlohmann::json::parse(out_.str())["v"].get<std::string>(), csi);
}

TEST_F(LogTest, LevelFilter) {
  set_log_level(LogLevel::warn);
  log_event(LogLevel::debug, "d", {});
  log_event(LogLevel::info, "i", {});
  log_event(LogLevel::warn, "w", {});
  log_event(LogLevel::error, "e", {});
  auto l = lines();
  ASSERT_EQ(l.size(), 2u) << out_.str();
  EXPECT_NE(l[0].find("level=warn event=w"), std::string::npos);
  EXPECT_NE(l[1].find("level=error event=e"), std::string::npos);
  clear();
  set_log_level(LogLevel::off);
  log_event(LogLevel::error, "e", {});
  EXPECT_TRUE(out_.str().empty());
  clear();
  set_log_level(LogLevel::debug);
  log_event(LogLevel::debug, "d", {});
  EXPECT_EQ(lines().size(), 1u);

  LogLevel level = LogLevel::info;
  EXPECT_TRUE(parse_log_level("error", level));
  EXPECT_EQ(level, LogLevel::error);
  EXPECT_FALSE(parse_log_level("loud", level));
  EXPECT_EQ(level, LogLevel::error);
  LogFormat format = LogFormat::text;
  EXPECT_TRUE(parse_log_format("json", format));
  EXPECT_EQ(format, LogFormat::json);
  EXPECT_FALSE(parse_log_format("xml", format));
}

TEST_F(LogTest, RateLimitPerEventReportsSuppressedCount) {
  set_log_rate_limit(5);
  for (int i = 0; i < 50; ++i) log_event(LogLevel::warn, "accept_failed", {{"i", i}});
  for (int i = 0; i < 3; ++i) log_event(LogLevel::warn, "other", {});
  auto l = lines();
  // 5 of accept_failed within the second, and another event is not held back by it.
  ASSERT_EQ(l.size(), 8u) << out_.str();
  for (const auto& line : l) EXPECT_EQ(line.find("suppressed="), std::string::npos) << line;
  clear();
  std::this_thread::sleep_for(std::chrono::milliseconds(1100));
  log_event(LogLevel::warn, "accept_failed", {{"i", 50}});
  log_event(LogLevel::warn, "accept_failed", {{"i", 51}});
  l = lines();
  ASSERT_EQ(l.size(), 2u) << out_.str();
  EXPECT_NE(l[0].find("i=50 suppressed=45"), std::string::npos) << l[0];
  EXPECT_EQ(l[1].find("suppressed="), std::string::npos) << l[1];
}

TEST_F(LogTest, LinesFromManyThreadsStayWhole) {
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t)
    threads.emplace_back([t] {
      for (int i = 0; i < 200; ++i)
        log_event(LogLevel::info, "t" + std::to_string(t), {{"payload", std::string(300, 'x')}});
    });
  for (auto& th : threads) th.join();
  const auto l = lines();
  ASSERT_EQ(l.size(), 800u);
  for (const auto& line : l) ASSERT_NE(line.find(" payload=" + std::string(300, 'x')), std::string::npos);
}

}  // namespace
