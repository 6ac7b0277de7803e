// SPDX-License-Identifier: Apache-2.0
// What the layer answers for VK_NV_cluster_acceleration_structure when it serves the extension.
//
// The served device is clastrace's engine: its EngineProperties are the one source of these
// limits, so what the application is told and what engine::execute enforces never differ.
#pragma once

#include <clastrace/engine/properties.h>
#include <clastrace/vk_cluster_abi.h>

namespace clastrace::capture {

inline engine::EngineProperties served_engine_properties() {
    return engine::EngineProperties::nvidia_default();
}

inline VkPhysicalDeviceClusterAccelerationStructurePropertiesNV served_cluster_properties() {
    VkPhysicalDeviceClusterAccelerationStructurePropertiesNV p = served_engine_properties().to_vk();
    p.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV;
    p.pNext = nullptr;
    return p;
}

}  // namespace clastrace::capture
