// SPDX-License-Identifier: Apache-2.0
// Resolving the command: its parameters, its indirected addresses and its op count.
#include "execute_command.h"

#include "clastrace/common/enum_bits.h"

#include <algorithm>

namespace clastrace::engine::detail {

using common::enum_bits;

namespace {

const char* src_infos_vuid(VkClusterAccelerationStructureOpTypeNV t) {
    switch (t) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
        return "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10448";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
        return "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10449";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
        return "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10450";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
        return "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10451";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV:
        return "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10452";
    default: return "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10832";
    }
}

// How many whole elements of `element` bytes at `stride` fit in `bytes`.
uint64_t elements_in(uint64_t bytes, uint64_t stride, uint64_t element) {
    if (bytes < element) return 0;
    return (bytes - element) / stride + 1;
}

bool has_op_input(const VkClusterAccelerationStructureInputInfoNV& input) {
    switch (input.opType) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
        return input.opInput.pMoveObjects != nullptr;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
        return input.opInput.pClustersBottomLevel != nullptr;
    default: return input.opInput.pTriangleClusters != nullptr;
    }
}

// An indirected field holds the address of the value; the cell read is recorded. A cell
// that cannot be read leaves `ok` false.
uint64_t resolve_field(CommandState& s, uint64_t value, uint32_t bit, const char* name, bool& ok) {
    if (!(s.command.addressResolutionFlags & bit) || value == 0) return value;
    std::string f = std::string(name) + " (indirected)";
    try {
        uint64_t v = s.memory.read<uint64_t>(value, {f.c_str(), -1});
        s.top.access(value, 8, kAccessIndirect, false, f);
        return v;
    } catch (const MemoryFault& fault) {
        s.top.fault(fault);
        ok = false;
        return 0;
    }
}

// min(count in memory, maxAccelerationStructureCount); srcInfosCount 0: the max.
uint64_t requested_op_count(CommandState& s) {
    const auto& input = s.input;
    const uint64_t count_address = s.cmd.count_address;
    if (s.command.srcInfosCount == 0) return input.maxAccelerationStructureCount;
    try {
        uint32_t in_memory = s.memory.read<uint32_t>(count_address, {"srcInfosCount", -1});
        s.top.access(count_address, 4, kAccessIndirect, false, "srcInfosCount");
        if (in_memory > input.maxAccelerationStructureCount)
            s.top.finding(
                "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10453",
                "srcInfosCount at " + hex(count_address) + " holds " + std::to_string(in_memory) +
                    ", more than input.maxAccelerationStructureCount = " +
                    std::to_string(input.maxAccelerationStructureCount) + "; the engine caps it",
                count_address);
        return std::min<uint64_t>(input.maxAccelerationStructureCount, in_memory);
    } catch (const MemoryFault& fault) {
        s.top.fault(fault);
        return 0;
    }
}

// Hostile counts: only as many ops as srcInfosArray really holds (10454).
uint64_t cap_to_src_infos(CommandState& s, uint64_t count, uint64_t stride) {
    const ResolvedCommand& cmd = s.cmd;
    uint64_t capacity = UINT64_MAX;
    std::string why;
    if (cmd.src_infos.size != 0) {
        capacity = elements_in(cmd.src_infos.size, stride, cmd.info_size);
        why = "srcInfosArray.size = " + std::to_string(cmd.src_infos.size);
    }
    const MemoryRegion* region = s.memory.find_region(cmd.src_infos.deviceAddress);
    uint64_t in_memory =
        region ? elements_in(region->base + region->size - cmd.src_infos.deviceAddress, stride,
                             cmd.info_size)
               : 0;
    if (in_memory < capacity) {
        capacity = in_memory;
        why = region
                  ? "the memory at srcInfosArray (" + hex(cmd.src_infos.deviceAddress) +
                        ", region '" + region->label + "')"
                  : "no memory at srcInfosArray.deviceAddress " + hex(cmd.src_infos.deviceAddress);
    }
    if (count <= capacity) return count;
    s.top.finding("VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10454",
                  "the op count is " + std::to_string(count) + " but " + why + " holds only " +
                      std::to_string(capacity) + " src infos; the engine runs those",
                  cmd.src_infos.deviceAddress);
    return capacity;
}

}  // namespace

void FindingSink::add(Finding f) {
    if (++counts[f.rule] <= cap) out.push_back(std::move(f));
}

void FindingSink::close() {
    for (const auto& [rule, n] : counts)
        if (n > cap)
            out.push_back({kRuleFindingsTruncated,
                           std::to_string(n - cap) + " more findings of rule " + rule +
                               " in this command were not kept",
                           -1, 0});
}

CommandState::CommandState(const VkClusterAccelerationStructureCommandsInfoNV& command,
                           MemoryImage& memory, const ExecuteOptions& options,
                           ExecutionRecord& record)
    : input(command.input),
      command(command),
      memory(memory),
      options(options),
      record(record),
      sink{record.findings, std::max<uint32_t>(1, options.max_findings_per_rule), {}},
      directory(options.directory ? *options.directory : local_directory) {
    // By their bits: check_parameters has not checked them yet (common/enum_bits.h).
    const uint32_t op_type = enum_bits(input.opType), op_mode = enum_bits(input.opMode);
    common::set_enum_bits(record.op_type, op_type);
    common::set_enum_bits(record.op_mode, op_mode);
    implicit = op_mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    explicit_mode = op_mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    sizes_only = op_mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV;
    is_move = op_type == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV;
}

void CommandState::flush_command_findings() {
    for (auto& f : top.findings) sink.add(std::move(f));
    top.findings.clear();
}

bool check_parameters(CommandState& s) {
    const auto& input = s.input;
    const uint32_t op_type = enum_bits(input.opType), op_mode = enum_bits(input.opMode);
    if (op_type > VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV) {
        s.sink.add({"VUID-VkClusterAccelerationStructureInputInfoNV-opType-parameter",
                    "input.opType = " + std::to_string(int(op_type)) +
                        " is not a VkClusterAccelerationStructureOpTypeNV",
                    -1, 0});
        return false;
    }
    if (op_mode > VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV) {
        s.sink.add({"VUID-VkClusterAccelerationStructureInputInfoNV-opMode-parameter",
                    "input.opMode = " + std::to_string(int(op_mode)) +
                        " is not a VkClusterAccelerationStructureOpModeNV",
                    -1, 0});
        return false;
    }
    if (!has_op_input(input)) {
        s.sink.add(
            {kRuleMissingInput,
             "input.opInput holds a null pointer for opType " + std::to_string(int(input.opType)),
             -1, 0});
        return false;
    }
    return true;
}

bool resolve_addresses(CommandState& s) {
    const auto& input = s.input;
    const auto& command = s.command;
    if (s.options.queried_max_count != 0 &&
        input.maxAccelerationStructureCount > s.options.queried_max_count)
        s.top.finding("VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10445",
                      "input.maxAccelerationStructureCount = " +
                          std::to_string(input.maxAccelerationStructureCount) + " exceeds the " +
                          std::to_string(s.options.queried_max_count) +
                          " the build sizes were queried with");
    bool ok = true;
    ResolvedCommand& cmd = s.cmd;
    cmd.op_type = input.opType;
    cmd.op_mode = input.opMode;
    cmd.input = &input;
    cmd.properties = &s.options.properties;
    cmd.directory = &s.directory;
    cmd.info_size = cluster_src_info_size(input.opType);
    cmd.src_infos = command.srcInfosArray;
    cmd.src_infos.deviceAddress = resolve_field(
        s, command.srcInfosArray.deviceAddress,
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV,
        "srcInfosArray", ok);
    cmd.scratch = resolve_field(
        s, command.scratchData,
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SCRATCH_DATA_BIT_NV,
        "scratchData", ok);
    if (s.implicit)
        cmd.implicit_data = resolve_field(
            s, command.dstImplicitData,
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_IMPLICIT_DATA_BIT_NV,
            "dstImplicitData", ok);
    if (!s.sizes_only) {
        cmd.dst_addresses = command.dstAddressesArray;
        cmd.dst_addresses.deviceAddress = resolve_field(
            s, command.dstAddressesArray.deviceAddress,
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV,
            "dstAddressesArray", ok);
    }
    cmd.dst_sizes = command.dstSizesArray;
    cmd.dst_sizes.deviceAddress = resolve_field(
        s, command.dstSizesArray.deviceAddress,
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV,
        "dstSizesArray", ok);
    cmd.count_address = resolve_field(
        s, command.srcInfosCount,
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV,
        "srcInfosCount", ok);
    s.record.scratch_address = cmd.scratch;
    s.record.implicit_address = cmd.implicit_data;
    if (!ok) {
        s.flush_command_findings();
        s.record.accesses = std::move(s.top.accesses);
    }
    return ok;
}

void resolve_op_count(CommandState& s) {
    ResolvedCommand& cmd = s.cmd;
    uint64_t count = requested_op_count(s);
    const uint64_t stride = cmd.src_infos.stride == 0 ? cmd.info_size : cmd.src_infos.stride;
    if (count > 0 && stride < cmd.info_size) {
        s.top.finding(src_infos_vuid(cmd.op_type),
                      "srcInfosArray.stride = " + std::to_string(stride) +
                          " is smaller than one src info (" + std::to_string(cmd.info_size) +
                          " bytes); no op runs");
        count = 0;
    }
    if (count > 0) count = cap_to_src_infos(s, count, stride);
    cmd.count = uint32_t(count);  // <= maxAccelerationStructureCount
    s.record.op_count = cmd.count;
    s.record.ops.resize(cmd.count);
}

}  // namespace clastrace::engine::detail
