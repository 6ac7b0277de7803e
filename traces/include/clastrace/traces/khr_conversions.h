// SPDX-License-Identifier: Apache-2.0
// VK_KHR_acceleration_structure build structs <-> their trace records, written once (see
// cluster_conversions.h): VkAccelerationStructureGeometryKHR, VkAccelerationStructureBuildRange-
// InfoKHR and VkAccelerationStructureBuildGeometryInfoKHR, every field. Only device-address
// inputs are recorded (host builds are not captured): the union members hold deviceAddress.
#pragma once

#include <clastrace/traces/trace_generated.h>
#include <clastrace/vk_cluster_abi.h>

#include <memory>
#include <vector>

namespace clastrace::traces {

// The geometry union's three members are recorded whatever geometryType says (unused ones as
// the application left them); pNext chains are not kept.
std::unique_ptr<fbs::GeometryKHRT> khr_geometry_to_record(
    const VkAccelerationStructureGeometryKHR& geometry);
// The member geometry_type names is filled (with its sType); the others are left zero.
VkAccelerationStructureGeometryKHR khr_geometry_from_record(const fbs::GeometryKHR& record);

fbs::BuildRangeInfoKHR khr_range_to_record(const VkAccelerationStructureBuildRangeInfoKHR& range);
VkAccelerationStructureBuildRangeInfoKHR khr_range_from_record(const fbs::BuildRangeInfoKHR& range);

// geometryCount geometries from pGeometries or ppGeometries (flattened), and `ranges` (one per
// geometry; null: none, as for an indirect build whose ranges are read at execution). The sTypes
// of the info's pNext chain go to unrecorded_next_stypes. The indirect fields are the caller's.
std::unique_ptr<fbs::AccelerationStructureBuildInfoKHRT> khr_build_info_to_record(
    const VkAccelerationStructureBuildGeometryInfoKHR& info,
    const VkAccelerationStructureBuildRangeInfoKHR* ranges);
// pGeometries points into `geometries` (replaced), ppGeometries is null; `ranges` (replaced)
// gets the record's ranges. The caller keeps both alive.
VkAccelerationStructureBuildGeometryInfoKHR khr_build_info_from_record(
    const fbs::AccelerationStructureBuildInfoKHR& record,
    std::vector<VkAccelerationStructureGeometryKHR>& geometries,
    std::vector<VkAccelerationStructureBuildRangeInfoKHR>& ranges);

}  // namespace clastrace::traces
