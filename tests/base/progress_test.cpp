#include "deepcanvas/base/progress.hpp"

#include <gtest/gtest.h>

#include <cstdio>
#include <string>

namespace {

using deepcanvas::base::format_duration;
using deepcanvas::base::Progress;

std::string read_all(std::FILE* f) {
  std::fflush(f);
  std::rewind(f);
  std::string out;
  char buf[256];
  while (std::size_t n = std::fread(buf, 1, sizeof buf, f)) out.append(buf, n);
  return out;
}

TEST(Progress, PlainLinesThenAClosingLine) {
  std::FILE* f = std::tmpfile();
  ASSERT_NE(f, nullptr);
  {
    Progress p("paint demo.apa", 10, "strokes");
    p.set_output(f, false);
    p.set_line_interval(0);  // a line for every update
    p.update(3);
    p.update(2);  // never goes back
    p.add(7);
    p.finish();
    p.finish();  // once only
  }
  const std::string text = read_all(f);
  std::fclose(f);
  EXPECT_NE(text.find("paint demo.apa: 3/10 strokes (30%)"), std::string::npos) << text;
  EXPECT_NE(text.find("paint demo.apa: 3/10 strokes (30%)", text.find("30%") + 1), std::string::npos)
      << "a smaller update shows what was done already\n" << text;
  EXPECT_NE(text.find("paint demo.apa: 10/10 strokes (100%)"), std::string::npos) << text;
  EXPECT_NE(text.find("paint demo.apa: 10/10 strokes in "), std::string::npos) << text;
  EXPECT_EQ(text.find('\r'), std::string::npos) << "no bar outside a terminal";
  const auto closing = text.find(" strokes in ");
  EXPECT_EQ(text.find(" strokes in ", closing + 1), std::string::npos) << "one closing line\n" << text;
}

TEST(Progress, TerminalBarIsRedrawnInPlace) {
  std::FILE* f = std::tmpfile();
  ASSERT_NE(f, nullptr);
  Progress p("replay", 4, "strokes");
  p.set_output(f, true);
  p.update(1);  // within 0.1 s of the start: not drawn yet
  p.finish();
  const std::string text = read_all(f);
  std::fclose(f);
  EXPECT_EQ(text.find("ETA"), std::string::npos) << text;
  EXPECT_NE(text.find("replay: 1/4 strokes in "), std::string::npos) << text;
}

TEST(Progress, DisabledWritesNothing) {
  std::FILE* f = std::tmpfile();
  ASSERT_NE(f, nullptr);
  {
    Progress p("quiet", 5, "steps", /*enabled=*/false);
    p.set_output(f, true);
    p.set_line_interval(0);
    p.update(5);
  }
  EXPECT_EQ(read_all(f), "");
  std::fclose(f);
}

TEST(Progress, Durations) {
  EXPECT_EQ(format_duration(0), "0.0 s");
  EXPECT_EQ(format_duration(0.34), "0.3 s");
  EXPECT_EQ(format_duration(12.4), "12 s");
  EXPECT_EQ(format_duration(59.4), "59 s");
  EXPECT_EQ(format_duration(65), "1:05");
  EXPECT_EQ(format_duration(7384), "2:03:04");
  EXPECT_EQ(format_duration(-1), "?");
}

}  // namespace
