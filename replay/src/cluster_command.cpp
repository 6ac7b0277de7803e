// SPDX-License-Identifier: Apache-2.0
#include "cluster_command.h"

#include "driver_sized_accesses.h"

#include <clastrace/common/enum_bits.h>
#include <clastrace/engine/build_sizes.h>
#include <clastrace/engine/execute.h>
#include <clastrace/traces/cluster_conversions.h>

#include <algorithm>
#include <chrono>
#include <cinttypes>
#include <cstddef>
#include <cstdio>
#include <cstring>
#include <memory>
#include <optional>
#include <string_view>
#include <unordered_set>

namespace clastrace::replay::detail {

namespace {

// Element size of srcInfosArray and where object addresses sit in one element.
struct InfoLayout {
    uint64_t size = 0;
    int64_t object_field = -1;  // offset of a VkDeviceAddress naming an object, -1 none
    const char* object_field_name = "";
    bool cluster_references =
        false;  // VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV
};

InfoLayout info_layout(uint32_t type) {
    switch (type) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
        return {sizeof(VkClusterAccelerationStructureMoveObjectsInfoNV),
                offsetof(VkClusterAccelerationStructureMoveObjectsInfoNV, srcAccelerationStructure),
                "srcAccelerationStructure", false};
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
        return {sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV), -1,
                "clusterReferences", true};
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV:
        return {sizeof(VkClusterAccelerationStructureInstantiateClusterInfoNV),
                offsetof(VkClusterAccelerationStructureInstantiateClusterInfoNV,
                         clusterTemplateAddress),
                "clusterTemplateAddress", false};
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV:
        return {sizeof(VkClusterAccelerationStructureGetTemplateIndicesInfoNV),
                offsetof(VkClusterAccelerationStructureGetTemplateIndicesInfoNV,
                         clusterTemplateAddress),
                "clusterTemplateAddress", false};
    default: return {};
    }
}

class Translator {
public:
    explicit Translator(ClusterCommandContext& c) : c_(c) {}

    // Rewrites the captured object addresses the command will read, in memory, before it runs.
    void run(const VkClusterAccelerationStructureCommandsInfoNV& info) {
        const InfoLayout layout = info_layout(common::enum_bits(info.input.opType));
        if (layout.size == 0) return;
        // Indirected arrays and counts are left to the engine as captured (not translated yet).
        if (info.addressResolutionFlags != 0) return;
        uint64_t count = info.input.maxAccelerationStructureCount;
        if (info.srcInfosCount != 0) {
            uint32_t n = 0;
            if (read(info.srcInfosCount, &n)) count = std::min<uint64_t>(count, n);
        }
        const uint64_t stride = info.srcInfosArray.stride ? info.srcInfosArray.stride : layout.size;
        if (stride < layout.size) return;
        if (info.srcInfosArray.size != 0) count = std::min(count, info.srcInfosArray.size / stride);
        const Elements infos =
            elements(info.srcInfosArray.deviceAddress, count, stride, layout.size);
        for (uint64_t i = 0; i < count; ++i) {
            const uint64_t element = info.srcInfosArray.deviceAddress + i * stride;
            if (layout.cluster_references) {
                VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV blas{};
                if (!infos.read(i, &blas) && !read(element, &blas)) return;
                const uint64_t ref_stride =
                    blas.clusterReferencesStride ? blas.clusterReferencesStride : 8;
                const Elements refs =
                    elements(blas.clusterReferences, blas.clusterReferencesCount, ref_stride, 8);
                for (uint64_t j = 0; j < blas.clusterReferencesCount; ++j) {
                    if (!cell(blas.clusterReferences + j * ref_stride, refs, j,
                              static_cast<int64_t>(i), "clusterReferences", j))
                        break;
                }
            } else if (!cell(element + static_cast<uint64_t>(layout.object_field), infos, i,
                             static_cast<int64_t>(i), layout.object_field_name, UINT64_MAX,
                             static_cast<uint64_t>(layout.object_field))) {
                return;
            }
        }
    }

private:
    // A strided array read in one piece when memory holds it whole (a fault leaves it empty,
    // and each element is then read on its own, stopping where memory ends, as before).
    struct Elements {
        std::span<const std::byte> bytes;
        uint64_t stride = 0;
        template <class T>
        bool read(uint64_t index, T* out, uint64_t offset = 0) const {
            if (bytes.empty() || index * stride + offset + sizeof(T) > bytes.size()) return false;
            std::memcpy(out, bytes.data() + index * stride + offset, sizeof(T));
            return true;
        }
    };
    Elements elements(uint64_t address, uint64_t count, uint64_t stride, uint64_t size) {
        if (count == 0) return {};
        try {
            return {c_.memory.image().read_array(address, count, stride, size, {"translation", -1}),
                    stride};
        } catch (const engine::MemoryFault&) {
            return {};
        }
    }

    template <class T>
    bool read(uint64_t address, T* out) {
        try {
            *out = c_.memory.image().read<T>(address, {"translation", -1});
            return true;
        } catch (const engine::MemoryFault&) {
            return false;
        }
    }

    // False when the cell is outside memory (the engine reports that itself).
    // `in`, `index`, `offset`: where the array read in one piece holds the cell's value.
    bool cell(uint64_t address, const Elements& in, uint64_t index, int64_t op, const char* field,
              uint64_t element, uint64_t offset = 0) {
        uint64_t value = 0;
        if (!in.read(index, &value, offset) && !read(address, &value)) return false;
        if (value == 0) return true;
        AddressTranslation& t = c_.translation;
        auto done = t.translated_cells.find(address);
        if (done != t.translated_cells.end() && done->second == value) return true;
        auto it = t.rebuilt_at.find(value);
        if (it != t.rebuilt_at.end()) {
            if (it->second != value) {
                c_.memory.image().write<uint64_t>(address, it->second, {"translation", op});
                ++c_.report.counts.addresses_translated;
            }
            t.translated_cells[address] = it->second;
            return true;
        }
        if (t.rebuilt.count(value) || c_.engine_trace) return true;
        // A driver trace names an object the replay never rebuilt (built before the capture
        // began, or by a command this replay skipped): the engine cannot read driver bytes.
        std::string where = std::string("srcInfosArray[") + std::to_string(op) + "]." + field;
        if (element != UINT64_MAX) where += "[" + std::to_string(element) + "]";
        c_.add_finding({"CLASTRACE-replay-reference-not-rebuilt",
                        where + " holds captured object address " + hex(value) +
                            ", which no replayed command built: it translates to no rebuilt object",
                        FindingSource::kReplay, c_.where, op, value});
        return true;
    }

    ClusterCommandContext& c_;
};

struct CapturedOutputs {
    std::vector<std::pair<uint64_t, std::vector<uint8_t>>> snapshots;  // address, bytes

    template <class T>
    bool value(uint64_t address, T* out) const {
        for (const auto& [base, bytes] : snapshots) {
            if (address >= base && address - base <= bytes.size() &&
                bytes.size() - (address - base) >= sizeof(T)) {
                std::memcpy(out, bytes.data() + (address - base), sizeof(T));
                return true;
            }
        }
        return false;
    }
};

std::string field_at(const engine::ExecutionRecord& record, uint64_t address, int64_t* op) {
    for (const engine::MemoryAccess& a : record.accesses) {
        if (a.is_write && address >= a.begin && address < a.end) {
            *op = a.op_index;
            return a.field.str();
        }
    }
    *op = -1;
    return "memory the engine did not write";
}

void verify(const fbs::CmdBuildClusterAccelerationStructureIndirect& build,
            const VkClusterAccelerationStructureCommandsInfoNV& info,
            const engine::ExecutionRecord& record, const ClusterDriverSizes& driver_sizes,
            ClusterCommandContext& c) {
    CapturedOutputs captured;
    if (build.outputs()) {
        for (const fbs::MemorySnapshot* s : *build.outputs()) {
            auto address = c.memory.snapshot_address(s->buffer(), s->offset(), s->address());
            std::vector<uint8_t> bytes;
            if (address && c.contents(s->hash(), &bytes))
                captured.snapshots.emplace_back(*address, std::move(bytes));
        }
    }
    const bool implicit = common::enum_bits(info.input.opMode) ==
                          VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    const bool sizes_written = common::enum_bits(info.input.opMode) !=
                               VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    const bool direct_addresses =
        !(info.addressResolutionFlags &
          VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV);
    const bool direct_sizes =
        !(info.addressResolutionFlags &
          VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV);
    const bool check = c.options.verify_outputs;
    SizeComparison sizes;
    sizes.where = c.where;
    sizes.op_type = common::enum_bits(info.input.opType);
    sizes.ops = static_cast<uint32_t>(record.ops.size());
    sizes.scratch_span = driver_sizes.build_scratch_size;
    sizes.destination_span = driver_sizes.acceleration_structure_size;
    sizes.spans_queried = driver_sizes.queried;

    for (size_t i = 0; i < record.ops.size(); ++i) {
        const engine::OpResult& op = record.ops[i];
        const auto op_index = static_cast<int64_t>(i);
        if (op.executed && op.dst_address != 0 &&
            common::enum_bits(info.input.opType) !=
                VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV) {
            c.translation.rebuilt.insert(op.dst_address);
            c.memory.mark_engine_object({op.dst_address, op.dst_address + op.dst_size});
        }
        if (implicit && direct_addresses && info.dstAddressesArray.deviceAddress != 0) {
            const uint64_t stride =
                info.dstAddressesArray.stride ? info.dstAddressesArray.stride : 8;
            uint64_t captured_address = 0;
            if (captured.value(info.dstAddressesArray.deviceAddress + i * stride,
                               &captured_address) &&
                captured_address != 0) {
                if (op.executed && op.dst_address != 0)
                    c.translation.rebuilt_at[captured_address] = op.dst_address;
                if (check && c.engine_trace && captured_address != op.dst_address) {
                    c.add_finding({"CLASTRACE-replay-output-differs",
                                   "dstAddressesArray[" + std::to_string(i) + "]: captured " +
                                       hex(captured_address) + ", engine " + hex(op.dst_address),
                                   FindingSource::kVerify, c.where, op_index,
                                   info.dstAddressesArray.deviceAddress + i * stride});
                }
            }
        }
        if (check && sizes_written && direct_sizes && info.dstSizesArray.deviceAddress != 0) {
            const uint64_t stride = info.dstSizesArray.stride ? info.dstSizesArray.stride : 4;
            uint32_t captured_size = 0;
            // An implicit object given room (implicit_object_room) reports the room it took.
            const uint64_t engine_size = implicit && op.executed
                                             ? std::max(op.dst_size, build.implicit_object_room())
                                             : op.dst_size;
            if (captured.value(info.dstSizesArray.deviceAddress + i * stride, &captured_size)) {
                ++sizes.ops_compared;
                if (sizes.first_ops.size() < SizeComparison::kOpsListed)
                    sizes.first_ops.push_back(
                        {static_cast<uint32_t>(i), captured_size, engine_size});
                sizes.captured_bytes += captured_size;
                sizes.engine_bytes += engine_size;
                if (captured_size == engine_size) {
                    ++sizes.sizes_equal;
                } else if (c.engine_trace) {
                    c.add_finding({"CLASTRACE-replay-output-differs",
                                   "dstSizesArray[" + std::to_string(i) + "]: captured " +
                                       std::to_string(captured_size) + " bytes, engine " +
                                       std::to_string(engine_size),
                                   FindingSource::kVerify, c.where, op_index,
                                   info.dstSizesArray.deviceAddress + i * stride});
                }
            }
        }
    }
    if (check && (sizes.ops_compared || !record.ops.empty())) {
        if (c.report.sizes.size() < c.options.max_command_rows)
            c.report.sizes.push_back(std::move(sizes));
        else
            ++c.report.rows_over_cap;
    }

    // A trace made by the engine must hold exactly the bytes the engine writes now.
    if (!check || !c.engine_trace) return;
    std::vector<uint8_t> now;
    for (const auto& [address, bytes] : captured.snapshots) {
        ++c.report.counts.outputs_compared;
        c.report.counts.output_bytes_compared += bytes.size();
        if (!c.memory.read(address, bytes.size(), &now)) continue;
        auto diff = std::mismatch(bytes.begin(), bytes.end(), now.begin());
        if (diff.first == bytes.end()) continue;
        const uint64_t at = address + static_cast<uint64_t>(diff.first - bytes.begin());
        int64_t op = -1;
        const std::string field = field_at(record, at, &op);
        c.add_finding({"CLASTRACE-replay-output-differs",
                       "captured output byte at " + hex(at) + " (" + field + ") is " +
                           hex(*diff.first) + ", the engine wrote " + hex(*diff.second) +
                           " (output snapshot at " + hex(address) + ", " +
                           std::to_string(bytes.size()) + " bytes)",
                       FindingSource::kVerify, c.where, op, at});
    }
}

// Explicit mode: the bytes each op's destination may take, as the driver reads them from
// dstSizesArray (when the command has one) or, without it, the answered per-object maximum.
std::vector<uint64_t> explicit_destination_spans(
    const VkClusterAccelerationStructureCommandsInfoNV& info, const engine::ExecutionRecord& record,
    const ClusterDriverSizes& sizes, ReplayMemory& memory) {
    std::vector<uint64_t> spans(record.ops.size(), sizes.acceleration_structure_size);
    const VkStridedDeviceAddressRegionKHR& array = info.dstSizesArray;
    if (array.deviceAddress == 0 ||
        (info.addressResolutionFlags &
         VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV))
        return spans;
    const uint64_t stride = array.stride ? array.stride : 4;
    for (size_t i = 0; i < spans.size(); ++i) {
        try {
            spans[i] = memory.image().read<uint32_t>(array.deviceAddress + i * stride,
                                                     {"dstSizesArray", int64_t(i)});
        } catch (const engine::MemoryFault&) {
            break;  // the engine reports the fault; the rest keep the answered maximum
        }
    }
    return spans;
}

// A served traceable cluster BLAS: the capture's memory there holds the driver's BVH from now
// on, so snapshots taken later of it must not replace the engine's object (ReplayMemory).
void mark_driver_bvh(const fbs::CmdBuildClusterAccelerationStructureIndirect& build,
                     ClusterCommandContext& c) {
    if (!build.driver_bvh()) return;
    for (const fbs::DeviceAddressRange* r : *build.driver_bvh()) {
        if (r->size() == 0 || r->address() + r->size() < r->address()) continue;
        c.memory.mark_driver_bvh({r->address(), r->address() + r->size()});
        ++c.report.counts.driver_bvh_ranges;
    }
}

}  // namespace

void run_cluster_command(const fbs::CmdBuildClusterAccelerationStructureIndirect& build,
                         uint32_t queried_max_count, const ClusterSizeQueries& queries,
                         ClusterCommandContext& c) {
    traces::ClusterOpInputStorage op_inputs;  // what info.input.opInput points to
    const VkClusterAccelerationStructureCommandsInfoNV info =
        traces::cluster_commands_from_record(build, op_inputs);
    Translator(c).run(info);
    const ClusterDriverSizes sizes = queries.sizes_for(info.input, c.properties);

    engine::ExecuteOptions options;
    options.properties = c.properties;
    options.directory = &c.directory;
    options.max_findings_per_rule = c.options.max_findings_per_rule;
    options.queried_max_count = queried_max_count;
    options.answered_sizes = sizes.answered();
    options.implicit_object_room = build.implicit_object_room();  // traceable BLASes' packing
    options.first_without_usage = [&c](uint64_t begin, uint64_t end, VkBufferUsageFlags usage) {
        return c.memory.first_without_usage(begin, end, usage);
    };
    engine::ExecutionRecord record;
    std::optional<DriverSizedAccesses> sized_ahead;  // what a run ahead made of its record
    const auto started = std::chrono::steady_clock::now();
    try {
        const bool ran_ahead =
            c.ahead && c.ahead->commit(c.memory, c.directory, queried_max_count, sizes, &record,
                                       c.engine_ns, &sized_ahead);
        if (!ran_ahead) {
            record = engine::execute(info, c.memory.image(), options);
            if (c.engine_ns)
                *c.engine_ns =
                    static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                              std::chrono::steady_clock::now() - started)
                                              .count());
        }
    } catch (const std::exception& e) {
        c.add_finding({"CLASTRACE-replay-engine-failed",
                       std::string("the engine stopped: ") + e.what(), FindingSource::kReplay,
                       c.where, -1, 0});
        return;
    }
    ++c.report.counts.cluster_commands;
    c.report.counts.cluster_ops += record.ops.size();
    // The engine checks the command's VkClusterAccelerationStructureTriangleClusterInputNV with
    // every op that uses it; it is one struct of the command: reported once, for the command.
    static constexpr std::string_view kInputRule =
        "VUID-VkClusterAccelerationStructureTriangleClusterInputNV-";
    std::unordered_set<std::string> input_rules;
    for (const engine::Finding& f : record.findings) {
        if (f.rule.starts_with(kInputRule)) {
            if (input_rules.insert(f.rule).second)
                c.add_finding({f.rule, "input.opInput.pTriangleClusters: " + f.message,
                               FindingSource::kEngine, c.where, -1, f.address});
            continue;
        }
        if (f.rule == engine::kRuleFindingsTruncated &&
            f.message.find(kInputRule) != std::string::npos)
            continue;
        c.add_finding({f.rule, f.message, FindingSource::kEngine, c.where, f.op_index, f.address});
    }
    std::shared_ptr<ModelAccesses> kept;  // with hazards checked, where the record went
    const engine::ExecutionRecord* ran = &record;
    if (c.options.check_hazards) {
        kept = std::make_shared<ModelAccesses>(std::move(record));
        ran = &kept->record;
        // One call for the command: the model keeps each per-op array as one range.
        const uint32_t op_mode = common::enum_bits(info.input.opMode);
        const bool implicit =
            op_mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
        const bool explicit_mode =
            op_mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
        const DriverSizedAccesses& sized =
            sized_ahead
                ? kept->sized.emplace(std::move(*sized_ahead))
                : kept->sized.emplace(*ran, implicit,
                                      explicit_mode
                                          ? explicit_destination_spans(info, *ran, sizes, c.memory)
                                          : std::vector<uint64_t>{},
                                      sizes);
        c.report.counts.accesses += sized.accesses.size();
        c.sync.record_accesses(c.ref, sized.accesses, kept);
        if (explicit_mode)  // rays through these BLASes read what the build may have written
            for (const Access& a : sized.accesses)
                if (a.is_write && a.field.starts_with("*dstAddressesArray["))
                    c.memory.mark_cluster_blas_span(a.range);
        if (implicit && build.implicit_object_room() != 0)  // the room each object took
            for (const Access& a : sized.accesses)
                if (a.is_write && a.field.starts_with("dstImplicitData["))
                    c.memory.mark_cluster_blas_span(
                        {a.range.begin,
                         engine::sat_add(a.range.begin, build.implicit_object_room())});
    }
    verify(build, info, *ran, sizes, c);
    mark_driver_bvh(build, c);
    if (!c.executed) return;
    if (kept)
        *c.executed = kept->record;  // the model's thread may still read it
    else
        *c.executed = std::move(record);
}

}  // namespace clastrace::replay::detail
