#include "deepcanvas/base/cli.hpp"

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

}  // namespace
