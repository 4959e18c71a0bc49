#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/base/cli_values.hpp"

#include <gtest/gtest.h>

#include <vector>

namespace {

namespace cli = deepcanvas::base::cli;

std::optional<int> run(std::vector<const char*> args, int& threads) {
  CLI::App app{"test command", "deepcanvas-test"};
  cli::standard(app, "examples:\n  deepcanvas-test --threads 4\n");
  app.add_option("--threads", threads, "threads")->check(CLI::Range(1, 64));
  args.insert(args.begin(), "deepcanvas-test");
  return cli::parse(app, static_cast<int>(args.size()), args.data());
}

TEST(Cli, ExitCodes) {
  int threads = 2;
  EXPECT_EQ(run({}, threads), std::nullopt);
  EXPECT_EQ(run({"--threads", "8"}, threads), std::nullopt);
  EXPECT_EQ(threads, 8);
  EXPECT_EQ(run({"--help"}, threads), 0);
  EXPECT_EQ(run({"--version"}, threads), 0);
  EXPECT_EQ(run({"--threads", "3x"}, threads), cli::kExitUsage);
  EXPECT_EQ(run({"--threads", "0"}, threads), cli::kExitUsage);
  EXPECT_EQ(run({"--threads"}, threads), cli::kExitUsage);
  EXPECT_EQ(run({"--no-such-option"}, threads), cli::kExitUsage);
}

TEST(Cli, BoxesAreSixFiniteNumbersMinimumFirst) {
  const auto b = cli::parse_box("-1,0,-2.5,1,2e1,+3");
  ASSERT_TRUE(b);
  EXPECT_EQ(*b, (std::array<double, 6>{-1, 0, -2.5, 1, 20, 3}));
  EXPECT_TRUE(cli::parse_box("0,0,0,0,0,0"));  // a point is a box
  for (const char* bad : {"", "1,2,3,4,5", "1,2,3,4,5,6,7", "1,2,3,0,5,6", "1,2,3,4,5,x",
                          "nan,0,0,1,1,1", "0,0,0,1,1,inf", "0,0,0,1,1,1,", " 0,0,0,1,1,1"})
    EXPECT_FALSE(cli::parse_box(bad)) << bad;
}

}  // namespace
