// SPDX-License-Identifier: Apache-2.0
// The options of an acceleration-structure build of either extension (NV, KHR): execute_khr_build
// runs its builds through the NV build's code, so one shape carries them across.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>

namespace clastrace::engine {

// The counts NVIDIA's driver reports, the same in VkPhysicalDeviceRayTracingPropertiesNV and
// VkPhysicalDeviceAccelerationStructurePropertiesKHR (2^24 - 1 and 2^29 - 1).
inline constexpr uint64_t kNvidiaMaxGeometryCount = 16777215;
inline constexpr uint64_t kNvidiaMaxInstanceCount = 16777215;
inline constexpr uint64_t kNvidiaMaxPrimitiveCount = 536870911;

// `Limits`: the extension's device properties the build checks (NvLimits, KhrLimits).
template <class Limits>
struct BuildOptions {
    Limits limits;
    // An instance's accelerationStructureReference (NV: a handle, KHR: a device address) -> the
    // engine address of that bottom level; nullopt when it names none. Default: the reference is
    // the address.
    std::function<std::optional<uint64_t>(uint64_t reference)> resolve_reference;
    uint32_t max_findings_per_rule = 64;
};

}  // namespace clastrace::engine
