// SPDX-License-Identifier: Apache-2.0
// Trace headers for hand-written traces. The driver name decides how replay treats captured
// outputs: "clastrace engine" marks a trace the engine itself produced (outputs must match to
// the byte), anything else a driver's (sizes may differ, addresses are translated).
#pragma once

#include <clastrace/engine/properties.h>
#include <clastrace/traces/trace_generated.h>

#include <memory>
#include <string>

namespace clastrace::trace_building {

inline constexpr const char* kEngineDriver = "clastrace engine";

fbs::TraceHeaderT trace_header(std::string device_name, std::string driver_name,
                               std::string capture_tool);

// VkPhysicalDeviceClusterAccelerationStructurePropertiesNV as the trace records it.
std::unique_ptr<fbs::ClusterPropertiesT> cluster_properties(const engine::EngineProperties& p);

}  // namespace clastrace::trace_building
