// Device choice policy and named errors (label unit, no device needed).
#include <gtest/gtest.h>

#include <cstdlib>

#include "deepcanvas/client_gpu/device_select.hpp"
#include "deepcanvas/client_gpu/errors.hpp"

namespace deepcanvas::client_gpu {
namespace {

DeviceInfo device(std::uint32_t index, std::string name, VkPhysicalDeviceType type,
                  std::uint64_t local = 1ull << 30, std::uint32_t api = VK_API_VERSION_1_3,
                  VkQueueFlags flags = VK_QUEUE_GRAPHICS_BIT | VK_QUEUE_COMPUTE_BIT |
                                       VK_QUEUE_TRANSFER_BIT) {
  DeviceInfo d;
  d.index = index;
  d.name = std::move(name);
  d.type = type;
  d.device_local_bytes = local;
  d.api_version = api;
  d.queue_families.push_back({0, flags, 1, 64});
  d.subgroup_size = 32;
  d.subgroup_stages = VK_SHADER_STAGE_COMPUTE_BIT;
  d.subgroup_operations = VK_SUBGROUP_FEATURE_BASIC_BIT | VK_SUBGROUP_FEATURE_BALLOT_BIT |
                          VK_SUBGROUP_FEATURE_ARITHMETIC_BIT;
  return d;
}

TEST(DeviceSelect, PrefersDiscreteThenIntegratedThenVirtualThenCpu) {
  const VkPhysicalDeviceType order[] = {VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU,
                                        VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU,
                                        VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU,
                                        VK_PHYSICAL_DEVICE_TYPE_CPU, VK_PHYSICAL_DEVICE_TYPE_OTHER};
  // Every subset of the five types, in every rotation: the best present type wins.
  for (unsigned mask = 1; mask < 32; ++mask) {
    for (unsigned rot = 0; rot < 5; ++rot) {
      std::vector<DeviceInfo> devs;
      for (unsigned k = 0; k < 5; ++k) {
        const unsigned t = (k + rot) % 5;
        if (mask & (1u << t)) {
          devs.push_back(
              device(static_cast<std::uint32_t>(devs.size()), "dev" + std::to_string(t), order[t]));
        }
      }
      unsigned best = 0;
      while (!(mask & (1u << best))) ++best;
      auto choice = select_device(devs, "");
      ASSERT_TRUE(choice) << choice.error().message;
      EXPECT_EQ(devs[choice->index].type, order[best]) << "mask " << mask << " rot " << rot;
      EXPECT_FALSE(choice->reason.empty());
    }
  }
}

TEST(DeviceSelect, TiesGoToTheLargerHeapThenTheLowerIndex) {
  std::vector<DeviceInfo> devs = {
      device(0, "small", VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU, 4ull << 30),
      device(1, "big", VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU, 16ull << 30),
      device(2, "big twin", VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU, 16ull << 30)};
  auto choice = select_device(devs, "");
  ASSERT_TRUE(choice);
  EXPECT_EQ(choice->index, 1u);
}

TEST(DeviceSelect, SkipsUnusableDevicesAndExplainsWhenNoneIsLeft) {
  std::vector<DeviceInfo> devs = {
      device(0, "old gpu", VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU, 8ull << 30, VK_API_VERSION_1_0),
      device(1, "graphics only", VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU, 8ull << 30,
             VK_API_VERSION_1_3, VK_QUEUE_GRAPHICS_BIT),
      device(2, "llvmpipe", VK_PHYSICAL_DEVICE_TYPE_CPU)};
  auto choice = select_device(devs, "");
  ASSERT_TRUE(choice);
  EXPECT_EQ(choice->index, 2u);
  EXPECT_NE(choice->reason.find("only usable"), std::string::npos) << choice->reason;
  EXPECT_NE(choice->reason.find("lavapipe"), std::string::npos) << choice->reason;

  devs.pop_back();
  auto none = select_device(devs, "");
  ASSERT_FALSE(none);
  EXPECT_EQ(gpu_errc_of(none.error()), GpuErrc::no_suitable_device);
  EXPECT_NE(none.error().message.find("no compute queue"), std::string::npos);
  EXPECT_NE(none.error().message.find("< 1.1"), std::string::npos);

  auto empty = select_device({}, "");
  ASSERT_FALSE(empty);
  EXPECT_EQ(gpu_errc_of(empty.error()), GpuErrc::no_device);
}

// The ray caster takes its work per subgroup and sums its loop counts (raycast.comp
// "Scheduling"): a device without ballot or arithmetic in compute shaders, or whose subgroups
// do not tile a 64-invocation workgroup, is skipped with the reason.
TEST(DeviceSelect, NeedsSubgroupBallotAndArithmeticInComputeWithASizeDividing64) {
  auto no_ballot = device(0, "no ballot", VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU);
  no_ballot.subgroup_operations =
      VK_SUBGROUP_FEATURE_BASIC_BIT | VK_SUBGROUP_FEATURE_ARITHMETIC_BIT;
  auto no_arithmetic = device(4, "no arithmetic", VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU);
  no_arithmetic.subgroup_operations =
      VK_SUBGROUP_FEATURE_BASIC_BIT | VK_SUBGROUP_FEATURE_BALLOT_BIT;
  auto fragment_only = device(1, "fragment only", VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU);
  fragment_only.subgroup_stages = VK_SHADER_STAGE_FRAGMENT_BIT;
  auto wide = device(2, "wide", VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU);
  wide.subgroup_size = 128;
  auto odd = device(3, "odd", VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU);
  odd.subgroup_size = 24;
  const std::string no_ops = "no subgroup ballot and arithmetic in compute shaders";
  EXPECT_EQ(unusable_reason(no_ballot), no_ops);
  EXPECT_EQ(unusable_reason(no_arithmetic), no_ops);
  EXPECT_EQ(unusable_reason(fragment_only), no_ops);
  EXPECT_EQ(unusable_reason(wide), "subgroup size 128 does not divide 64");
  EXPECT_EQ(unusable_reason(odd), "subgroup size 24 does not divide 64");
  for (std::uint32_t size : {1u, 4u, 8u, 16u, 32u, 64u}) {
    auto ok = device(0, "ok", VK_PHYSICAL_DEVICE_TYPE_CPU);
    ok.subgroup_size = size;
    EXPECT_EQ(unusable_reason(ok), "") << size;
  }
  std::vector<DeviceInfo> devs = {no_ballot, fragment_only, wide, no_arithmetic,
                                  device(3, "llvmpipe", VK_PHYSICAL_DEVICE_TYPE_CPU)};
  auto choice = select_device(devs, "");
  ASSERT_TRUE(choice);
  EXPECT_EQ(choice->index, 3u);
  devs.pop_back();
  auto none = select_device(devs, "");
  ASSERT_FALSE(none);
  EXPECT_NE(none.error().message.find("subgroup size 128"), std::string::npos);
}

TEST(DeviceSelect, OverrideByIndexOrCaseInsensitiveNameBeatsThePolicy) {
  std::vector<DeviceInfo> devs = {
      device(0, "NVIDIA GeForce RTX", VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU),
      device(1, "llvmpipe (LLVM 15)", VK_PHYSICAL_DEVICE_TYPE_CPU)};
  auto by_index = select_device(devs, "1");
  ASSERT_TRUE(by_index);
  EXPECT_EQ(by_index->index, 1u);
  EXPECT_NE(by_index->reason.find("requested"), std::string::npos);
  auto by_name = select_device(devs, "LLVMPIPE");
  ASSERT_TRUE(by_name);
  EXPECT_EQ(by_name->index, 1u);
  auto by_name2 = select_device(devs, "geforce");
  ASSERT_TRUE(by_name2);
  EXPECT_EQ(by_name2->index, 0u);

  for (const char* bad : {"2", "radeon", "17"}) {
    auto r = select_device(devs, bad);
    ASSERT_FALSE(r) << bad;
    EXPECT_EQ(gpu_errc_of(r.error()), GpuErrc::device_not_found);
    EXPECT_NE(r.error().message.find("llvmpipe"), std::string::npos) << "lists the devices";
  }
  devs[1].queue_families[0].flags = VK_QUEUE_TRANSFER_BIT;
  auto unusable = select_device(devs, "1");
  ASSERT_FALSE(unusable);
  EXPECT_EQ(gpu_errc_of(unusable.error()), GpuErrc::no_suitable_device);
}

TEST(DeviceSelect, CommandLineBeatsTheEnvironment) {
  ::setenv(kDeviceEnvVar, "from-env", 1);
  EXPECT_EQ(device_override_from("from-cli"), "from-cli");
  EXPECT_EQ(device_override_from(""), "from-env");
  ::unsetenv(kDeviceEnvVar);
  EXPECT_EQ(device_override_from(""), "");
}

TEST(DeviceSelect, Formatting) {
  EXPECT_EQ(format_api_version(VK_MAKE_API_VERSION(0, 1, 3, 230)), "1.3.230");
  EXPECT_EQ(format_queue_flags(VK_QUEUE_COMPUTE_BIT | VK_QUEUE_TRANSFER_BIT), "COMPUTE|TRANSFER");
  EXPECT_EQ(format_queue_flags(0), "none");
  EXPECT_EQ(device_type_name(VK_PHYSICAL_DEVICE_TYPE_CPU), "CPU");
}

TEST(GpuErrors, EveryNameRoundTripsThroughAnError) {
  for (int i = 0; i < kGpuErrcCount; ++i) {
    const auto code = static_cast<GpuErrc>(i);
    const Error e = gpu_error(code, "something went wrong", VK_ERROR_OUT_OF_DEVICE_MEMORY);
    EXPECT_EQ(gpu_errc_of(e), code) << e.message;
    EXPECT_EQ(e.message.rfind("vulkan." + std::string(gpu_errc_name(code)) + ": ", 0), 0u);
    EXPECT_NE(e.message.find("(ErrorOutOfDeviceMemory)"), std::string::npos);
  }
  EXPECT_FALSE(gpu_errc_of(make_error(Errc::internal, "plain error")));
  EXPECT_FALSE(gpu_errc_of(make_error(Errc::internal, "vulkan.no_such_name: x")));
  EXPECT_EQ(gpu_errc_of(gpu_error_from(VK_ERROR_DEVICE_LOST, GpuErrc::submit_failed, "x")),
            GpuErrc::device_lost);
  EXPECT_EQ(gpu_errc_of(gpu_error_from(VK_ERROR_OUT_OF_HOST_MEMORY, GpuErrc::submit_failed, "x")),
            GpuErrc::out_of_memory);
  EXPECT_EQ(gpu_error(GpuErrc::device_not_found, "x").code, Errc::not_found);
  EXPECT_EQ(vk_result_name(VK_ERROR_INCOMPATIBLE_DRIVER), "ErrorIncompatibleDriver");
  EXPECT_EQ(vk_result_name(static_cast<VkResult>(-12345)), "invalid ( ffffcfc7 )");
}

}  // namespace
}  // namespace deepcanvas::client_gpu
