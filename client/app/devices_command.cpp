// `deepcanvas-client devices`: every Vulkan physical device the loader sees, and which one the
// client would use and why (the same policy as every other command, device_select.hpp).
#include <cinttypes>
#include <cstdio>
#include <string>

#include <nlohmann/json.hpp>

#include "cli_options.hpp"
#include "commands.hpp"
#include "deepcanvas/base/cli.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/client_gpu/context.hpp"
#include "deepcanvas/client_gpu/device_select.hpp"
#include "deepcanvas/client_gpu/errors.hpp"
#include "deepcanvas/client_gpu/self_check.hpp"
#include "pool_layout.h"

namespace deepcanvas::client_app {
namespace {

namespace cli = deepcanvas::base::cli;
namespace gpu = deepcanvas::client_gpu;
namespace layout = deepcanvas::gpu_layout;

constexpr const char* kDescription =
    "Lists every Vulkan physical device (name, type, driver, API version, limits that matter to\n"
    "deepcanvas, queue families) and says which one the client would use and why: discrete\n"
    "GPU > integrated GPU > virtual GPU > CPU (lavapipe), among devices with Vulkan 1.1, a\n"
    "compute queue and subgroup ballot in compute shaders.\n"
    "\n"
    "Exit status: 0 when the client would use a device (the one --device names, if given)\n"
    "and, with --check, the check passes; 1 otherwise; 2 on bad options.\n";

constexpr const char* kExamples =
    "Examples:\n"
    "  deepcanvas-client devices\n"
    "  deepcanvas-client devices --check\n"
    "      also run one compute dispatch on the chosen device and verify its result\n"
    "  deepcanvas-client devices --device llvmpipe --json\n";

std::string driver_version_string(const gpu::DeviceInfo& d) {
  char buf[64];
  const std::uint32_t v = d.driver_version;
  if (d.vendor_id == 0x10DE) {  // NVIDIA packs 10.8.8.6 bits
    std::snprintf(buf, sizeof buf, "%u.%u.%u.%u", v >> 22, (v >> 14) & 0xFF, (v >> 6) & 0xFF,
                  v & 0x3F);
    return buf;
  }
  return gpu::format_api_version(v);
}

// The widest pool texture the device allows (a power of two up to 16384) and the cells it holds.
std::uint32_t pool_width(const gpu::DeviceInfo& d) {
  std::uint32_t w = 1u << layout::kMaxWidthLog2;
  while (w > d.max_image_dimension_2d && w > 1) w >>= 1;
  return w;
}

std::string human_bytes(std::uint64_t b) {
  char buf[64];
  if (b >= (1ull << 30)) {
    std::snprintf(buf, sizeof buf, "%.2f GiB", static_cast<double>(b) / (1ull << 30));
  } else {
    std::snprintf(buf, sizeof buf, "%.1f MiB", static_cast<double>(b) / (1ull << 20));
  }
  return buf;
}

void print_text(const gpu::Instance& inst, const std::vector<gpu::DeviceInfo>& devices) {
  std::printf("Vulkan loader %s, %zu physical device%s%s\n",
              gpu::format_api_version(inst.loader_version()).c_str(), devices.size(),
              devices.size() == 1 ? "" : "s",
              inst.validation_enabled() ? ", validation layer on" : "");
  for (const auto& d : devices) {
    std::printf("\n[%u] %s\n", d.index, d.name.c_str());
    std::printf("    type                 %s\n",
                std::string(gpu::device_type_name(d.type)).c_str());
    std::printf("    driver               %s%s%s%s (driver version %s)\n",
                d.driver_name.empty() ? "(unnamed)" : d.driver_name.c_str(),
                d.driver_info.empty() ? "" : " [", d.driver_info.c_str(),
                d.driver_info.empty() ? "" : "]", driver_version_string(d).c_str());
    std::printf("    Vulkan API           %s\n", gpu::format_api_version(d.api_version).c_str());
    std::printf("    vendor / device id   0x%04x / 0x%04x\n", d.vendor_id, d.device_id);
    const std::uint32_t w = pool_width(d);
    std::printf("    max 2D image         %u x %u (pool textures %u wide: up to %" PRIu64
                " cells)\n",
                d.max_image_dimension_2d, d.max_image_dimension_2d, w,
                static_cast<std::uint64_t>(w) * d.max_image_dimension_2d);
    std::printf("    max storage buffer   %u bytes (%s)\n", d.max_storage_buffer_range,
                human_bytes(d.max_storage_buffer_range).c_str());
    std::printf("    push constants       %u bytes\n", d.max_push_constants_size);
    std::printf("    device-local memory  %s\n", human_bytes(d.device_local_bytes).c_str());
    std::printf("    timestamp period     %.3g ns\n", static_cast<double>(d.timestamp_period_ns));
    std::printf("    subgroups            %u lanes, ballot and arithmetic in compute: %s\n",
                d.subgroup_size, gpu::has_compute_subgroup_ops(d) ? "yes" : "no");
    std::printf("    queue families\n");
    for (const auto& q : d.queue_families) {
      std::printf("      #%u %-28s x%-3u timestamps: %s\n", q.index,
                  gpu::format_queue_flags(q.flags).c_str(), q.count,
                  q.timestamp_valid_bits > 0
                      ? (std::to_string(q.timestamp_valid_bits) + " bits").c_str()
                      : "no");
    }
    const std::string why = gpu::unusable_reason(d);
    std::printf("    usable               %s\n", why.empty() ? "yes" : ("no: " + why).c_str());
  }
}

nlohmann::json to_json(const gpu::DeviceInfo& d) {
  nlohmann::json q = nlohmann::json::array();
  for (const auto& f : d.queue_families) {
    q.push_back({{"index", f.index},
                 {"flags", gpu::format_queue_flags(f.flags)},
                 {"count", f.count},
                 {"timestamp_valid_bits", f.timestamp_valid_bits}});
  }
  const std::string why = gpu::unusable_reason(d);
  return {{"index", d.index},
          {"name", d.name},
          {"type", std::string(gpu::device_type_name(d.type))},
          {"driver_name", d.driver_name},
          {"driver_info", d.driver_info},
          {"driver_version", driver_version_string(d)},
          {"api_version", gpu::format_api_version(d.api_version)},
          {"vendor_id", d.vendor_id},
          {"device_id", d.device_id},
          {"max_image_dimension_2d", d.max_image_dimension_2d},
          {"max_storage_buffer_range", d.max_storage_buffer_range},
          {"max_push_constants_size", d.max_push_constants_size},
          {"device_local_bytes", d.device_local_bytes},
          {"timestamp_period_ns", d.timestamp_period_ns},
          {"subgroup_size", d.subgroup_size},
          {"subgroup_compute_ops", gpu::has_compute_subgroup_ops(d)},
          {"queue_families", q},
          {"usable", why.empty()},
          {"unusable_reason", why}};
}

int run_devices(int argc, char** argv) {
  std::string device_cli;
  bool json = false;
  bool check = false;
  CLI::App app{kDescription, "deepcanvas-client devices"};
  cli::standard(app, kExamples);
  app.add_option("--device", device_cli,
                 "pretend this device was requested: index I, or the first device whose name "
                 "contains NAME (case-insensitive); default: $DEEPCANVAS_VK_DEVICE, else "
                 "automatic")
      ->type_name("I|NAME");
  app.add_flag("--check", check,
               "create a context on the device the client would use and verify one compute "
               "dispatch on it (prints 'self-check: ok, ...')");
  app.add_flag("--json", json, "one JSON object instead of text");
  wrap_help(app);
  if (auto code = cli::parse(app, argc, argv)) return *code;

  auto inst = gpu::InstanceBuilder().app_name("deepcanvas-client devices").build();
  if (!inst) return cli::fail(app, inst.error().message);
  if (!inst->validation_note().empty()) {
    base::log_event(base::LogLevel::warn, "vulkan_validation_unavailable",
                    {{"note", inst->validation_note()}});
  }
  auto devices = inst->devices();
  if (!devices) return cli::fail(app, devices.error().message);
  const std::string override_spec = gpu::device_override_from(device_cli);
  auto choice = gpu::select_device(*devices, override_spec);

  // --check: a real context on the chosen device and one verified dispatch.
  std::string check_text;
  bool check_ok = true;
  if (check && choice) {
    auto ctx =
        gpu::ContextBuilder().app_name("deepcanvas-client devices").device(device_cli).build();
    auto report =
        ctx ? gpu::self_check(**ctx) : deepcanvas::Result<gpu::SelfCheckReport>(ctx.error());
    check_ok = report.ok();
    if (report) {
      check_text = "ok, " + std::to_string(report->invocations) + " invocations verified";
      if (report->dispatch_ns) {
        char buf[64];
        std::snprintf(buf, sizeof buf, " (dispatch %.1f us)", *report->dispatch_ns / 1000.0);
        check_text += buf;
      }
    } else {
      check_text = "FAILED: " + report.error().message;
    }
  }

  if (json) {
    nlohmann::json out;
    out["loader_api_version"] = gpu::format_api_version(inst->loader_version());
    out["devices"] = nlohmann::json::array();
    for (const auto& d : *devices) out["devices"].push_back(to_json(d));
    out["override"] = override_spec;
    if (choice) {
      out["selected"] = choice->index;
      out["reason"] = choice->reason;
      if (check) {
        out["check_ok"] = check_ok;
        out["check"] = check_text;
      }
    } else {
      out["selected"] = nullptr;
      out["error"] = choice.error().message;
    }
    std::printf("%s\n", out.dump(2).c_str());
  } else {
    print_text(*inst, *devices);
    std::printf("\n");
    if (choice) {
      std::printf("would use: [%u] %s\n  because: %s%s\n", choice->index,
                  (*devices)[choice->index].name.c_str(), choice->reason.c_str(),
                  override_spec.empty() ? ""
                  : device_cli.empty()  ? " (from $DEEPCANVAS_VK_DEVICE)"
                                        : " (from --device)");
      if (check) std::printf("self-check: %s\n", check_text.c_str());
    }
  }
  if (!choice) return cli::fail(app, choice.error().message);
  return check_ok ? 0 : cli::kExitRuntime;
}

}  // namespace

DEEPCANVAS_CLIENT_COMMAND("devices", "list Vulkan devices and the one the client would use",
                          run_devices);

}  // namespace deepcanvas::client_app
