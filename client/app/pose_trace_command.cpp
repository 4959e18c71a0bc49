// `deepcanvas-client pose-trace`: writes a realistic head and controller motion (a pose trace,
// client_core/pose_trace.hpp) around a painting or a box, for `watch --stereo`, the headset
// benchmark and scripted headset input.
#include <cstdio>
#include <fstream>
#include <string>

#include "cli_options.hpp"
#include "commands.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/client_core/pose_trace.hpp"
#include "deepcanvas/paintings/apa.hpp"

namespace deepcanvas::client_app {
namespace {

namespace cli = deepcanvas::base::cli;

constexpr const char* kDescription =
    "Writes a pose trace: an artist standing before the content (a painting's strokes, or a box\n"
    "in canvas metres) at a world scale that fits it in about 1.5 m, turning the head to look\n"
    "around it, leaning in every 8 s to paint (the controller tip over the content, the trigger\n"
    "pressed in strokes of about a second) and once scaling the world 8x about the content with\n"
    "a two-handed grab and back. Deterministic for a --seed. The file is text, one sample a\n"
    "line (its format is at the top of the file, and in docs/operations.md).\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-client pose-trace --painting demo.apa --seconds 60 --out head.trace\n"
    "  deepcanvas-client pose-trace --box -1,0,-1,1,2,1 --hz 90 --seed 3 --out head.trace\n";

int run_pose_trace(int argc, char** argv) {
  std::string out, painting, box;
  double seconds = 30, hz = 90;
  std::uint64_t seed = 1;
  CLI::App app{kDescription, "deepcanvas-client pose-trace"};
  cli::standard(app, kExamples);
  app.add_option("--out", out, "the trace file to write (required)")->type_name("FILE")->check(output_file());
  auto* p = app.add_option("--painting", painting, "frame this painting's strokes")->type_name("FILE.apa");
  app.add_option("--box", box, "frame this box instead (canvas metres)")
      ->type_name("X0,Y0,Z0,X1,Y1,Z1")
      ->check(box_corners())
      ->excludes(p);
  app.add_option("--seconds", seconds, "length (default 30)")->type_name("S")->transform(number(0.1, 86400));
  app.add_option("--hz", hz, "samples a second (default 90)")->type_name("HZ")->transform(number(1, 1000));
  app.add_option("--seed", seed, "the motion's random seed (default 1)")->type_name("N");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;
  if (out.empty()) return usage_error(app, "--out FILE is required");
  client_core::DAabb content = client_core::empty_box();
  if (!painting.empty()) {
    auto apa = paintings::read_apa_file(painting, {});
    if (!apa) return cli::fail(app, apa.error().message);
    for (const auto& s : apa->strokes) client_core::grow_by_samples(content, s.samples);
    if (content.min.x > content.max.x) return cli::fail(app, painting + ": no samples");
  } else if (!box.empty()) {
    const auto v = *parse_box(box);  // checked by the option's box_corners() validator
    content = {{v[0], v[1], v[2]}, {v[3], v[4], v[5]}};
  } else {
    return usage_error(app, "give --painting FILE.apa or --box");
  }
  const auto trace = client_core::generate_pose_trace(content, seconds, seed, hz);
  std::ofstream f(out, std::ios::binary | std::ios::trunc);
  f << client_core::format_pose_trace(trace);
  f.close();
  if (!f) return cli::fail(app, "cannot write " + out);
  std::printf("wrote %s: %zu samples, %.1f s at %.0f Hz\n", out.c_str(), trace.samples.size(),
              trace.duration_s(), hz);
  return 0;
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("pose-trace", "write a head and controller motion for headset runs",
                          run_pose_trace);

}  // namespace deepcanvas::client_app
