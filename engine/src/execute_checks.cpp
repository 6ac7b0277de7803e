// SPDX-License-Identifier: Apache-2.0
// The command's checks: buffer usage (one table), scratch and destinations before the ops
// run; overlaps, moved bytes, totals and intra-command hazards after.
#include "clastrace/engine/build_sizes.h"
#include "execute_command.h"

#include "clastrace/common/enum_bits.h"

#include <algorithm>
#include <initializer_list>
#include <optional>

namespace clastrace::engine::detail {

namespace {

// What a usage row checks: an address, and for UsedElements its stride (0: packed) and
// the bytes of one element.
struct UsageTarget {
    uint64_t address;
    uint64_t stride = 0;
    uint64_t element = 0;
};

struct UsageCheck {
    const char* vuid;
    const char* field;  // the command's field, as findings name it
    UsageExtent extent;
    VkBufferUsageFlags usage;  // the bit the buffer must have been created with
    UsageTarget (*target)(const ResolvedCommand&);
};

// Table order is findings order within each extent.
constexpr UsageCheck kUsageChecks[] = {
    {"VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12304", "scratchData",
     UsageExtent::kFirstByte, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
     [](const ResolvedCommand& c) { return UsageTarget{c.scratch}; }},
    {"VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12306", "srcInfosCount",
     UsageExtent::kFirstByte, VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR,
     [](const ResolvedCommand& c) { return UsageTarget{c.count_address}; }},
    {"VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12308", "dstImplicitData",
     UsageExtent::kFirstByte, VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR,
     [](const ResolvedCommand& c) { return UsageTarget{c.implicit_data}; }},
    {"VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12305", "srcInfosArray",
     UsageExtent::kUsedElements,
     VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR,
     [](const ResolvedCommand& c) {
         return UsageTarget{c.src_infos.deviceAddress, c.src_infos.stride, c.info_size};
     }},
    {"VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12307",
     "dstAddressesArray", UsageExtent::kUsedElements,
     VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR,
     [](const ResolvedCommand& c) {
         return UsageTarget{c.dst_addresses.deviceAddress, c.dst_addresses.stride, 8};
     }},
};

// ExecuteOptions::first_without_usage when the caller has no buffer list: the image's
// regions, each with one usage (0: unknown, taken as allowed); bytes in no region are the
// memory rules' business.
std::optional<uint64_t> first_region_without_usage(const MemoryImage& memory, uint64_t begin,
                                                   uint64_t end, VkBufferUsageFlags bit) {
    const auto& regions = memory.regions();
    auto it = regions.upper_bound(begin);
    if (it != regions.begin()) --it;
    for (; it != regions.end() && it->first < end; ++it) {
        const MemoryRegion& r = it->second;
        if (r.base + r.size <= begin) continue;
        if (r.usage != 0 && !(r.usage & bit)) return std::max(begin, r.base);
    }
    return std::nullopt;
}

// The buffer holding the address, where the trace recorded its usage (0: unknown, not checked).
void check_first_byte_usage(CommandState& s, const UsageCheck& row, uint64_t address) {
    const MemoryRegion* region = s.memory.find_region(address);
    if (region && region->usage != 0 && !(region->usage & row.usage))
        s.top.finding(row.vuid,
                      std::string(row.field) + " " + hex(address) + " lies in buffer '" +
                          region->label + "', which was not created with the usage it requires",
                      address);
}

// 12305/12307 name a "device address range": every byte of the elements the ops use, up
// to the last one's end (with no op, the first byte), must lie in a buffer with the usage.
void check_used_elements_usage(CommandState& s, const UsageCheck& row, const UsageTarget& target) {
    const uint32_t count = s.cmd.count;
    uint64_t bytes = 1;
    if (count > 0) {
        const uint64_t step = target.stride == 0 ? target.element : target.stride;
        if (step != 0 && uint64_t(count - 1) > (UINT64_MAX - target.element) / step)
            return;  // wraps: faults say so
        bytes = uint64_t(count - 1) * step + target.element;
    }
    const uint64_t address = target.address;
    const uint64_t end = address + bytes < address ? UINT64_MAX : address + bytes;
    const std::optional<uint64_t> bad =
        s.options.first_without_usage
            ? s.options.first_without_usage(address, end, row.usage)
            : first_region_without_usage(s.memory, address, end, row.usage);
    if (!bad) return;
    const MemoryRegion* region = s.memory.find_region(*bad);
    s.top.finding(row.vuid,
                  std::string(row.field) + " spans [" + hex(address) + ", " + hex(end) +
                      "); its byte " + hex(*bad) +
                      (region ? " (buffer '" + region->label + "')" : std::string()) +
                      " lies in no buffer created with the usage it requires",
                  *bad);
}

// Reports op `w.op`'s range where it starts below the end of an earlier-starting one.
void check_overlaps(CommandState& s, std::vector<Written> v, const char* rule, const char* what) {
    std::sort(v.begin(), v.end(), [](const Written& a, const Written& b) {
        return a.begin < b.begin || (a.begin == b.begin && a.op < b.op);
    });
    uint64_t reach = 0;
    int64_t reach_op = -1;
    for (const Written& w : v) {
        if (reach_op >= 0 && w.begin < reach)
            s.top.finding(rule,
                          std::string(what) + ": op " + std::to_string(w.op) + "'s object [" +
                              hex(w.begin) + ", " + hex(w.end) + ") overlaps op " +
                              std::to_string(reach_op) + "'s, which ends at " + hex(reach) +
                              " (the higher op index's bytes are kept)",
                          w.begin);
        if (w.end > reach) {
            reach = w.end;
            reach_op = w.op;
        }
    }
}

// The scratch bytes the command may write, [first, second); empty when it uses none. A
// driver may touch every byte it answered: with answered sizes the range spans them.
std::pair<uint64_t, uint64_t> scratch_span(const CommandState& s) {
    const ResolvedCommand& cmd = s.cmd;
    if (cmd.scratch == 0 || s.record.scratch_bytes_used == 0) return {0, 0};
    const auto& answered = s.options.answered_sizes;
    const uint64_t scratch_size =
        answered ? std::max(answered->build_scratch_size, s.record.scratch_bytes_used)
                 : s.record.scratch_bytes_used;
    return {cmd.scratch, sat_add(cmd.scratch, scratch_size)};
}

// 12303 (implicit data) and 12302 (explicit destinations) against the scratch the ops used.
void check_scratch_overlaps(CommandState& s) {
    const ResolvedCommand& cmd = s.cmd;
    const auto [s0, s1] = scratch_span(s);
    if (s0 == s1) return;
    const auto& answered = s.options.answered_sizes;
    const uint64_t implicit_size =
        answered ? std::max(answered->acceleration_structure_size, s.cursor) : s.cursor;
    const uint64_t i0 = cmd.implicit_data, i1 = sat_add(cmd.implicit_data, implicit_size);
    if (s.implicit && s.cursor > 0 && i0 < s1 && s0 < i1)
        s.top.finding("VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-dstImplicitData-12303",
                      "dstImplicitData [" + hex(i0) + ", " + hex(i1) + ") overlaps scratchData [" +
                          hex(s0) + ", " + hex(s1) + ")",
                      cmd.implicit_data);
    if (s.explicit_mode)
        for (const Written& w : s.written)
            if (w.begin < s1 && s0 < w.end)
                s.top.finding(
                    "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-dstAddressesArray-12302",
                    "op " + std::to_string(w.op) + "'s destination [" + hex(w.begin) + ", " +
                        hex(w.end) + ") overlaps scratchData [" + hex(s0) + ", " + hex(s1) + ")",
                    w.begin);
}

void check_moves(CommandState& s) {
    const auto& mv = *s.input.opInput.pMoveObjects;
    if (s.moved_bytes > mv.maxMovedBytes)
        s.top.finding(kRuleMovedBytesAboveInput,
                      "the command moves " + std::to_string(s.moved_bytes) +
                          " bytes, more than maxMovedBytes = " + std::to_string(mv.maxMovedBytes));
    if (!mv.noMoveOverlap) return;
    std::vector<Written> dsts = s.written;
    std::sort(dsts.begin(), dsts.end(),
              [](const Written& a, const Written& b) { return a.op < b.op; });
    for (const Written& src : s.move_sources) {
        auto it = std::lower_bound(dsts.begin(), dsts.end(), src.op,
                                   [](const Written& w, int64_t op) { return w.op < op; });
        if (it != dsts.end() && it->op == src.op && it->begin < src.end && src.begin < it->end)
            // Named at the op that moves (a checker keyed on the op finds it there).
            s.top.findings.push_back(
                Finding{kRuleMoveOverlap,
                        "op " + std::to_string(src.op) + " moves [" + hex(src.begin) + ", " +
                            hex(src.end) + ") onto an overlapping destination at " +
                            hex(it->begin) + " although noMoveOverlap is VK_TRUE",
                        src.op, src.begin});
    }
}

// The *Total* limits of the input against what the ops built.
void check_totals(CommandState& s) {
    if (s.input.opType ==
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV) {
        const auto& bl = *s.input.opInput.pClustersBottomLevel;
        if (s.total_clusters > bl.maxTotalClusterCount)
            s.top.finding(kRuleTotalAboveInput, "the command references " +
                                                    std::to_string(s.total_clusters) +
                                                    " clusters, more than maxTotalClusterCount = " +
                                                    std::to_string(bl.maxTotalClusterCount));
        return;
    }
    if (s.input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV)
        return;
    const auto& tc = *s.input.opInput.pTriangleClusters;
    if (s.total_triangles > tc.maxTotalTriangleCount)
        s.top.finding(kRuleTotalAboveInput, "the command builds " +
                                                std::to_string(s.total_triangles) +
                                                " triangles, more than maxTotalTriangleCount = " +
                                                std::to_string(tc.maxTotalTriangleCount));
    if (s.total_vertices > tc.maxTotalVertexCount)
        s.top.finding(kRuleTotalAboveInput, "the command builds " +
                                                std::to_string(s.total_vertices) +
                                                " vertices, more than maxTotalVertexCount = " +
                                                std::to_string(tc.maxTotalVertexCount));
}

// The op writes sorted by start, and per write the earlier-starting write reaching
// furthest: one look-up per read, O(log n), however the writes nest.
struct WriteIndex {
    std::vector<const MemoryAccess*> writes;
    std::vector<size_t> reach;

    explicit WriteIndex(const std::vector<MemoryAccess>& accesses) {
        writes.reserve(size_t(std::count_if(accesses.begin(), accesses.end(),
                                            [](const MemoryAccess& a) { return a.is_write; })));
        for (const auto& a : accesses)
            if (a.is_write) writes.push_back(&a);
        std::sort(writes.begin(), writes.end(), [](const MemoryAccess* a, const MemoryAccess* b) {
            return a->begin < b->begin || (a->begin == b->begin && a->op_index < b->op_index);
        });
        reach.resize(writes.size());
        for (size_t k = 0; k < writes.size(); ++k)
            reach[k] = k && writes[reach[k - 1]]->end >= writes[k]->end ? reach[k - 1] : k;
    }

    // A write overlapping [begin, end), or null.
    const MemoryAccess* overlapping(uint64_t begin, uint64_t end) const {
        auto it = std::lower_bound(writes.begin(), writes.end(), end,
                                   [](const MemoryAccess* w, uint64_t v) { return w->begin < v; });
        if (it == writes.begin()) return nullptr;
        const MemoryAccess* w = writes[reach[size_t(it - writes.begin()) - 1]];
        return w->end <= begin ? nullptr : w;
    }
};

}  // namespace

void check_buffer_usage(CommandState& s, UsageExtent extent) {
    for (const UsageCheck& row : kUsageChecks) {
        if (row.extent != extent) continue;
        const UsageTarget target = row.target(s.cmd);
        if (target.address == 0) continue;
        if (extent == UsageExtent::kFirstByte)
            check_first_byte_usage(s, row, target.address);
        else
            check_used_elements_usage(s, row, target);
    }
}

// The engine's (offset, size) table in scratch; 12300 against the answered size when the
// caller has one, else against the engine's own worst case for the (queried) input.
void check_scratch(CommandState& s) {
    const ResolvedCommand& cmd = s.cmd;
    const EngineProperties& props = s.options.properties;
    uint64_t required = 0;
    std::string origin = " bytes the build sizes require";
    if (s.options.answered_sizes) {
        required = s.options.answered_sizes->build_scratch_size;
        origin = "-byte buildScratchSize " + s.options.answered_sizes->source;
    } else {
        VkClusterAccelerationStructureInputInfoNV queried_input = s.input;
        if (s.options.queried_max_count != 0)
            queried_input.maxAccelerationStructureCount = s.options.queried_max_count;
        required = cluster_build_sizes(queried_input, props).build_scratch_size;
    }
    if (required == 0) return;
    const MemoryRegion* region = s.memory.find_region(cmd.scratch);
    uint64_t available = region ? region->base + region->size - cmd.scratch : 0;
    if (available < required) {
        s.top.finding(kRuleScratchTooSmall,
                      "scratchData " + hex(cmd.scratch) + " has " + std::to_string(available) +
                          " bytes of memory, less than the " + std::to_string(required) + origin,
                      cmd.scratch);
        s.scratch_usable = available >= scratch_bytes_for_ops(cmd.count);
    }
    if (props.cluster_scratch_byte_alignment > 1 &&
        cmd.scratch % props.cluster_scratch_byte_alignment != 0)
        s.top.finding(kRuleScratchMisaligned,
                      "scratchData " + hex(cmd.scratch) +
                          " is not a multiple of clusterScratchByteAlignment = " +
                          std::to_string(props.cluster_scratch_byte_alignment),
                      cmd.scratch);
}

void check_destinations(CommandState& s) {
    const ResolvedCommand& cmd = s.cmd;
    // The move input's type is never checked: it goes by its bits (common/enum_bits.h).
    s.align =
        destination_alignment(s.input.opType,
                              s.is_move ? common::enum_bits(s.input.opInput.pMoveObjects->type)
                                        : VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_MAX_ENUM_NV,
                              s.options.properties);
    if (s.implicit && cmd.count > 0 && cmd.implicit_data % s.align != 0)
        s.top.finding(kRuleDestinationMisaligned,
                      "dstImplicitData " + hex(cmd.implicit_data) + " is not a multiple of the " +
                          std::to_string(s.align) + "-byte object alignment",
                      cmd.implicit_data);
    if (s.sizes_only && cmd.count > 0 && cmd.dst_sizes.deviceAddress == 0)
        s.top.finding(kRuleMissingSizesArray,
                      "opMode is VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV but "
                      "dstSizesArray is 0");
}

void check_whole_command(CommandState& s) {
    if (s.explicit_mode)
        check_overlaps(
            s, s.written,
            "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-dstAddressesArray-12302",
            "destinations in dstAddressesArray overlap");
    check_scratch_overlaps(s);
    if (s.is_move)
        check_moves(s);
    else
        check_totals(s);
}

// No order exists between the ops of one command: a range one op reads and another op (or
// the same op, through another field) writes is undefined on a GPU. (Moves without
// noMoveOverlap may overlap their own source: the spec allows it.)
void check_intra_command_hazards(CommandState& s) {
    const WriteIndex index(s.op_accesses);
    const auto [s0, s1] = scratch_span(s);
    uint64_t hazards = 0;
    // The command's reads (srcInfosCount, indirection cells) first, then the ops'.
    for (const std::vector<MemoryAccess>* accesses : {&s.top.accesses, &s.op_accesses}) {
        for (const MemoryAccess& read : *accesses) {
            if (read.is_write) continue;
            if (read.begin < s1 && s0 < read.end) {  // scratch sub-allocated over an input
                if (++hazards <= s.options.max_findings_per_rule)
                    s.top.finding(kRuleIntraCommandHazard,
                                  "op " + std::to_string(read.op_index) + " reads " + read.field +
                                      " [" + hex(read.begin) + ", " + hex(read.end) +
                                      ") which the command writes as scratchData [" + hex(s0) +
                                      ", " + hex(s1) + ")",
                                  std::max(read.begin, s0));
                else
                    s.top.finding(kRuleIntraCommandHazard, "");
                continue;
            }
            const MemoryAccess* w = index.overlapping(read.begin, read.end);
            if (!w) continue;
            if (s.is_move && w->op_index == read.op_index)
                continue;  // a move may overlap its own source
            if (++hazards >
                s.options.max_findings_per_rule) {  // counted by the sink, not spelled out
                s.top.finding(kRuleIntraCommandHazard, "");
                continue;
            }
            s.top.finding(kRuleIntraCommandHazard,
                          "op " + std::to_string(read.op_index) + " reads " + read.field + " [" +
                              hex(read.begin) + ", " + hex(read.end) + ") which op " +
                              std::to_string(w->op_index) + " writes as " + w->field +
                              " in the same command",
                          std::max(read.begin, w->begin));
        }
    }
}

}  // namespace clastrace::engine::detail
