// SPDX-License-Identifier: Apache-2.0
// Shared between the command's stages (execute*.cpp) and execute_ops.cpp (one op each).
#pragma once

#include "clastrace/common/hex.h"
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/execute.h"
#include "clastrace/engine/execution_record.h"

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace clastrace::engine::detail {

using common::hex;

// Accesses and findings of one op (or of the command), gathered without locks.
struct Recorder {
    std::vector<MemoryAccess> accesses;
    std::vector<Finding> findings;
    int64_t op_index = -1;

    void access(uint64_t begin, uint64_t size, VkAccessFlags2 access, bool is_write,
                FieldName field);
    void finding(const char* rule, std::string message, uint64_t address = 0);
    void fault(const MemoryFault& f);
};

// The command after address resolution and count capping.
struct ResolvedCommand {
    VkClusterAccelerationStructureOpTypeNV op_type;
    VkClusterAccelerationStructureOpModeNV op_mode;
    const VkClusterAccelerationStructureInputInfoNV* input;
    uint64_t implicit_data = 0;
    uint64_t scratch = 0;
    uint64_t count_address = 0;  // srcInfosCount, resolved
    VkStridedDeviceAddressRegionKHR dst_addresses{};
    VkStridedDeviceAddressRegionKHR dst_sizes{};
    VkStridedDeviceAddressRegionKHR src_infos{};
    uint64_t info_size = 0;  // bytes of one src info struct
    uint32_t count = 0;
    const EngineProperties* properties = nullptr;
    const ObjectDirectory* directory = nullptr;
};

// What one op produced in the read phase.
struct OpOutput {
    Recorder rec;
    std::vector<std::byte> bytes;  // the object, empty on failure
    bool ok = false;
    ObjectType type = ObjectType::kTriangleCluster;
    uint64_t explicit_dst = 0;  // explicit mode: dstAddressesArray[i]
    uint64_t move_src = 0;      // moves: the source address
    uint64_t move_src_size = 0;
    bool is_object = true;  // false for template indices (not an engine object)
    uint64_t triangles = 0, vertices = 0, clusters = 0;  // for the *Total* input limits
};

// Runs op `index` in the read phase: never writes memory, never throws.
void run_op(const ResolvedCommand& cmd, const MemoryImage& memory, uint32_t index,
            ClusterBuilder& builder, OpOutput& out);

}  // namespace clastrace::engine::detail
