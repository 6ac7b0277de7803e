// SPDX-License-Identifier: Apache-2.0
// VK_NV_ray_tracing acceleration-structure structs <-> their trace records, written once (see
// cluster_conversions.h): VkGeometryNV and VkAccelerationStructureInfoNV, every field.
#pragma once

#include <clastrace/traces/trace_generated.h>
#include <clastrace/vk_cluster_abi.h>

#include <memory>
#include <vector>

namespace clastrace::traces {

// VkGeometryDataNV holds both members whatever geometryType says: both are recorded.
std::unique_ptr<fbs::GeometryNVT> nv_geometry_to_record(const VkGeometryNV& geometry);
// A member the record lacks reads as zeros (with its sType).
VkGeometryNV nv_geometry_from_record(const fbs::GeometryNV& record);

// geometryCount geometries from pGeometries; pNext chains are not kept.
std::unique_ptr<fbs::AccelerationStructureInfoNVT> nv_info_to_record(
    const VkAccelerationStructureInfoNV& info);
// pGeometries points into `geometries` (replaced), which the caller keeps alive.
VkAccelerationStructureInfoNV nv_info_from_record(const fbs::AccelerationStructureInfoNV& record,
                                                  std::vector<VkGeometryNV>& geometries);

}  // namespace clastrace::traces
