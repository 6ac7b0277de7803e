// SPDX-License-Identifier: Apache-2.0
// KHR acceleration-structure commands on the engine (khr_command.h).
#include "khr_command.h"

#include <clastrace/engine/khr_build.h>
#include <clastrace/engine/nv_serialize.h>

#include <chrono>
#include <cstring>

namespace clastrace::replay::detail {
namespace {

constexpr VkPipelineStageFlags2 kStageCopy =
    VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR;
constexpr VkAccessFlags2 kObjectRead = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;
constexpr VkAccessFlags2 kObjectWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
constexpr const char* kRuleSerializedPastDst = "CLASTRACE-replay-khr-serialized-past-dst";
// vkCmdCopyAccelerationStructureNV's src-04963: the VUID catalogue keeps one name per number
// (the KHR struct's), so the NV form is reported under the tool's own rule.
constexpr const char* kRuleNvCopySrcNotBuilt = "CLASTRACE-nv-copy-src-not-built";

uint64_t elapsed_ns(std::chrono::steady_clock::time_point started) {
    return uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(
                        std::chrono::steady_clock::now() - started)
                        .count());
}

engine::KhrGeometry geometry_of(const fbs::GeometryKHR& g) {
    engine::KhrGeometry out;
    out.type = VkGeometryTypeKHR(g.geometry_type());
    out.flags = g.flags();
    if (const fbs::GeometryTrianglesKHR* t = g.triangles()) {
        out.triangles.vertex_format = VkFormat(t->vertex_format());
        out.triangles.vertex_data = t->vertex_data();
        out.triangles.vertex_stride = t->vertex_stride();
        out.triangles.max_vertex = t->max_vertex();
        out.triangles.index_type = VkIndexType(t->index_type());
        out.triangles.index_data = t->index_data();
        out.triangles.transform_data = t->transform_data();
    }
    if (const fbs::GeometryAabbsKHR* a = g.aabbs()) out.aabbs = {a->data(), a->stride()};
    if (const fbs::GeometryInstancesKHR* i = g.instances())
        out.instances = {i->array_of_pointers(), i->data()};
    return out;
}

const char* query_type_name(uint32_t type) {
    switch (type) {
    case VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_KHR: return "compacted size";
    case VK_QUERY_TYPE_ACCELERATION_STRUCTURE_COMPACTED_SIZE_NV: return "compacted size (NV)";
    case VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR: return "serialization size";
    case VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SIZE_KHR: return "size";
    case VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_BOTTOM_LEVEL_POINTERS_KHR:
        return "serialization bottom-level pointers";
    default: return "unknown query type";
    }
}

}  // namespace

void KhrReplay::on_create(const fbs::AccelerationStructureCreate& create) {
    if (create.api() == 1) types_[create.acceleration_structure()] = create.type();
}

std::optional<uint64_t> KhrReplay::resolve_reference(uint64_t reference) {
    if (std::optional<uint64_t> shadow = k_.nv.resolve(reference, false)) return shadow;
    if (auto it = k_.translation.rebuilt_at.find(reference);
        it != k_.translation.rebuilt_at.end()) {
        ++k_.nv.c_.report.counts.handles_translated;
        return it->second;
    }
    if (k_.translation.rebuilt.count(reference) || k_.nv.c_.report.engine_trace) return reference;
    return std::nullopt;
}

engine::KhrObject KhrReplay::khr_object(uint64_t handle, const char* field, uint64_t at_least,
                                        const ReplayLocation& where) {
    engine::KhrObject out;
    out.handle = handle;
    if (handle == 0) return out;
    NvReplay::Object* o = k_.nv.object(handle);
    if (!o) {
        k_.nv.c_.add_finding(
            {kRuleKhrUnknownObject,
             std::string(field) + " " + hex(handle) + " was never created in the trace",
             FindingSource::kReplay, where, -1, 0});
        out.bound = false;
        return out;
    }
    if (auto t = types_.find(handle); t != types_.end())
        out.type = VkAccelerationStructureTypeKHR(t->second);
    out.bound = o->bound && k_.nv.ensure_shadow(*o, where, at_least);
    if (out.bound) {
        out.address = o->shadow;
        out.size = o->shadow_size;
    }
    return out;
}

uint64_t KhrReplay::bytes_to_end_of_buffer(uint64_t address) const {
    const engine::MemoryRegion* r = k_.nv.c_.memory.image().find_region(address);
    return r && address != 0 ? r->base + r->size - address : 0;
}

engine::KhrBuildInfo KhrReplay::build_info(const fbs::AccelerationStructureBuildInfoKHR& in,
                                           const std::string& field, const ReplayLocation& where) {
    engine::KhrBuildInfo info;
    info.type = VkAccelerationStructureTypeKHR(in.type());
    info.flags = in.flags();
    info.mode = VkBuildAccelerationStructureModeKHR(in.mode());
    if (in.geometries())
        for (const fbs::GeometryKHR* g : *in.geometries())
            info.geometries.push_back(geometry_of(*g));
    std::vector<uint32_t> counts;
    if (in.ranges())
        for (const fbs::BuildRangeInfoKHR* r : *in.ranges()) {
            info.ranges.push_back({r->primitive_count(), r->primitive_offset(), r->first_vertex(),
                                   r->transform_offset()});
            counts.push_back(r->primitive_count());
        }
    info.scratch_address = in.scratch_address();
    // A driver's trace sized scratch by the driver's answer, not the engine's: the engine's
    // own claim is not held against it (its accesses are cut to the buffer below). So did any
    // application that asked the driver for this build's sizes, in an engine trace too: a
    // served trace's KHR builds ran on the device's driver, and its answer is in the trace.
    const uint64_t answer = driver_scratch(in, counts);
    info.scratch_available = k_.nv.c_.report.engine_trace && answer == 0
                                 ? bytes_to_end_of_buffer(info.scratch_address)
                                 : ~0ull;
    if (answer) info.scratch_claim = answer;
    const uint64_t need = info.ranges.size() == info.geometries.size()
                              ? engine::khr_build_sizes(info.type, info.geometries, counts)
                                    .acceleration_structure_size
                              : 0;
    info.dst =
        khr_object(in.dst(), (field + ".dstAccelerationStructure").c_str(),
                   info.mode == VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR ? 0 : need, where);
    if (in.src() != 0)
        info.src = khr_object(in.src(), (field + ".srcAccelerationStructure").c_str(), 0, where);
    return info;
}

void KhrReplay::build_sizes(const fbs::GetAccelerationStructureBuildSizesKHR& sizes) {
    if (!sizes.info()) return;
    DriverSizes d{
        sizes.info()->type(), {}, {}, sizes.build_scratch_size(), sizes.update_scratch_size()};
    if (sizes.info()->geometries())
        for (const fbs::GeometryKHR* g : *sizes.info()->geometries())
            d.geometry_types.push_back(g->geometry_type());
    if (sizes.max_primitive_counts())
        d.max_primitive_counts.assign(sizes.max_primitive_counts()->begin(),
                                      sizes.max_primitive_counts()->end());
    driver_sizes_.push_back(std::move(d));
}

// The smallest scratch the driver named for a build of this shape (same type and geometry
// types, at least these primitive counts): the application sized its region by such an
// answer. 0 when it asked for none.
uint64_t KhrReplay::driver_scratch(const fbs::AccelerationStructureBuildInfoKHR& in,
                                   const std::vector<uint32_t>& counts) const {
    const bool update = in.mode() == VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR;
    uint64_t best = 0;
    for (const DriverSizes& d : driver_sizes_) {
        if (d.type != in.type() || !in.geometries() ||
            d.geometry_types.size() != in.geometries()->size() ||
            d.max_primitive_counts.size() != counts.size())
            continue;
        bool covers = true;
        for (size_t g = 0; g < counts.size() && covers; ++g)
            covers = d.geometry_types[g] == in.geometries()->Get(uint32_t(g))->geometry_type() &&
                     d.max_primitive_counts[g] >= counts[g];
        const uint64_t scratch = update ? d.update_scratch : d.build_scratch;
        if (covers && scratch != 0 && (best == 0 || scratch < best)) best = scratch;
    }
    return best;
}

void KhrReplay::mark_built(uint64_t handle, uint32_t flags) {
    if (NvReplay::Object* o = k_.nv.object(handle)) {
        o->built = true;
        o->opaque = false;
        o->built_flags = flags;
    }
}

void KhrReplay::build(const fbs::CmdBuildAccelerationStructuresKHR& b, const CommandRef& ref,
                      const ReplayLocation& where) {
    NvReplayContext& c = k_.nv.c_;
    c.lay_in_snapshots(b.inputs(), where);
    ++c.report.counts.khr_builds;
    engine::KhrBuildCommand cmd;
    if (b.infos())
        for (const fbs::AccelerationStructureBuildInfoKHR* in : *b.infos())
            cmd.infos.push_back(
                build_info(*in, "pInfos[" + std::to_string(cmd.infos.size()) + "]", where));
    engine::KhrBuildOptions options;
    options.max_findings_per_rule = c.options.max_findings_per_rule;
    options.resolve_reference = [this](uint64_t r) { return resolve_reference(r); };
    const auto started = std::chrono::steady_clock::now();
    engine::ExecutionRecord record = engine::execute_khr_build(cmd, c.memory.image(), options);
    const uint64_t engine_ns = elapsed_ns(started);
    for (engine::MemoryAccess& a : record.accesses) {
        // A top level's read of a cluster bottom level an instance names spans the room its
        // build was modelled to write (the driver's BVH may fill it), as the rays' reads do.
        if (!a.is_write && a.field.ends_with(".accelerationStructureReference"))
            if (std::optional<AddressRange> span = c.memory.cluster_blas_span(a.begin))
                a.end = std::max(a.end, span->end);
        if (a.field.ends_with(".scratchData") && a.begin != 0) {
            const bool by_answer = a.op_index >= 0 && size_t(a.op_index) < cmd.infos.size() &&
                                   cmd.infos[size_t(a.op_index)].scratch_claim != ~0ull;
            if (c.report.engine_trace && !by_answer) continue;  // the engine's own sizes hold
            const uint64_t in_buffer = bytes_to_end_of_buffer(a.begin);
            if (in_buffer && a.end - a.begin > in_buffer) a.end = a.begin + in_buffer;
            // The driver's scratch, not the engine's: the region the application sized.
            if (a.op_index >= 0 && size_t(a.op_index) < cmd.infos.size())
                a.end = a.begin +
                        std::min(a.end - a.begin, cmd.infos[size_t(a.op_index)].scratch_claim);
        }
    }
    k_.nv.engine_findings(record, where);
    k_.nv.feed(ref, record, where);
    for (size_t i = 0; i < cmd.infos.size() && i < record.ops.size(); ++i)
        if (record.ops[i].executed) mark_built(cmd.infos[i].dst.handle, cmd.infos[i].flags);
    if (c.observe) c.observe(std::move(record), engine_ns);
}

uint64_t KhrReplay::engine_object_size(uint64_t handle, bool* top_level) {
    NvReplay::Object* o = k_.nv.object(handle);
    if (!o || !o->built || o->opaque || !o->shadow) return 0;
    try {
        auto head = k_.nv.c_.memory.image().read_bytes(o->shadow, sizeof(engine::NvObjectHeader),
                                                       {"acceleration structure", -1});
        std::optional<engine::NvObjectHeader> h = engine::read_nv_header(head, nullptr);
        if (!h || h->object_size > o->shadow_size) return 0;
        if (top_level) *top_level = h->kind == uint8_t(engine::NvObjectKind::kTopLevel);
        return h->object_size;
    } catch (const engine::MemoryFault&) {
        return 0;
    }
}

void KhrReplay::copy(const fbs::CmdCopyAccelerationStructure& copy, const CommandRef& ref,
                     const ReplayLocation& where) {
    NvReplayContext& c = k_.nv.c_;
    c.lay_in_snapshots(copy.inputs(), where);
    const bool khr = copy.api() == 1;
    const std::string prefix = khr ? "pInfo->" : "";
    NvReplay::Object* src = k_.nv.object(copy.src());
    NvReplay::Object* dst = k_.nv.object(copy.dst());
    auto unknown = [&](const char* name, uint64_t handle) {
        c.add_finding({kRuleKhrUnknownObject,
                       prefix + name + " " + hex(handle) + " was never created in the trace",
                       FindingSource::kReplay, where, -1, 0});
    };
    if (!src) unknown("src", copy.src());
    if (!dst) unknown("dst", copy.dst());
    if (!src || !dst) return;
    ++c.report.counts.khr_copies;
    // Both sides are accessed whatever the engine can do with them.
    if (c.options.check_hazards) {
        auto s = c.memory.object_range(src->handle), d = c.memory.object_range(dst->handle);
        if (s && d) {
            c.report.counts.accesses += 2;
            c.sync.record_copy(ref, Access{*s, kStageCopy, kObjectRead, false, prefix + "src"},
                               Access{*d, kStageCopy, kObjectWrite, true, prefix + "dst"});
        }
    }
    const uint64_t size = engine_object_size(src->handle);
    if (size == 0) {
        c.add_finding(
            {khr ? "VUID-VkCopyAccelerationStructureInfoKHR-src-04963" : kRuleNvCopySrcNotBuilt,
             prefix + "src " + hex(src->handle) +
                 " holds no acceleration structure the replay built before this copy",
             FindingSource::kEngine, where, -1, 0});
        return;
    }
    if (khr && copy.mode() == VK_COPY_ACCELERATION_STRUCTURE_MODE_COMPACT_KHR &&
        !(src->built_flags & VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_COMPACTION_BIT_KHR))
        c.add_finding({"VUID-VkCopyAccelerationStructureInfoKHR-src-03411",
                       "pInfo->src " + hex(src->handle) +
                           " was last built without "
                           "VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_COMPACTION_BIT_KHR; mode is "
                           "VK_COPY_ACCELERATION_STRUCTURE_MODE_COMPACT_KHR",
                       FindingSource::kEngine, where, -1, 0});
    // Clone and compact write the same bytes: the engine's objects are already compact, and
    // top levels name their bottom levels by engine address, so the copy needs no patching.
    if (!dst->bound || !k_.nv.ensure_shadow(*dst, where, size)) return;
    auto bytes = c.memory.image().read_bytes(src->shadow, size, {"pInfo->src", -1});
    const std::vector<std::byte> copied(bytes.begin(), bytes.end());
    std::memcpy(c.memory.image().write_bytes(dst->shadow, size, {"pInfo->dst", -1}).data(),
                copied.data(), size);
    mark_built(dst->handle, src->built_flags);
}

void KhrReplay::copy_to_memory(const fbs::CmdCopyAccelerationStructureToMemory& copy,
                               const CommandRef& ref, const ReplayLocation& where) {
    NvReplayContext& c = k_.nv.c_;
    c.lay_in_snapshots(copy.inputs(), where);
    NvReplay::Object* src = k_.nv.object(copy.src());
    if (!src) {
        c.add_finding({kRuleKhrUnknownObject,
                       "pInfo->src " + hex(copy.src()) + " was never created in the trace",
                       FindingSource::kReplay, where, -1, 0});
        return;
    }
    ++c.report.counts.khr_copies;
    std::string error;
    const std::vector<std::byte> blob =
        src->built && !src->opaque && src->shadow
            ? engine::serialize_nv_object(c.memory.image(), src->shadow, &error)
            : std::vector<std::byte>{};
    if (c.options.check_hazards)
        if (auto s = c.memory.object_range(src->handle)) {
            const uint64_t written = blob.empty() ? 56 : blob.size();  // at least the header
            c.report.counts.accesses += 2;
            c.sync.record_copy(ref, Access{*s, kStageCopy, kObjectRead, false, "pInfo->src"},
                               Access{{copy.dst_address(), copy.dst_address() + written},
                                      kStageCopy,
                                      VK_ACCESS_2_TRANSFER_WRITE_BIT,
                                      true,
                                      "pInfo->dst.deviceAddress"});
        }
    if (blob.empty()) {
        c.add_finding({"VUID-VkCopyAccelerationStructureToMemoryInfoKHR-src-04959",
                       "pInfo->src " + hex(src->handle) +
                           " holds no acceleration structure the replay built before this "
                           "serialization" +
                           (error.empty() ? "" : ": " + error),
                       FindingSource::kEngine, where, -1, 0});
        return;
    }
    const auto* data = reinterpret_cast<const uint8_t*>(blob.data());
    if (!c.memory.write(copy.dst_address(), {data, blob.size()}))
        c.add_finding({kRuleSerializedPastDst,
                       "the engine's serialized form of " + hex(src->handle) + " (" +
                           std::to_string(blob.size()) + " bytes) does not fit in the memory at " +
                           "pInfo->dst " + hex(copy.dst_address()) +
                           ", sized by the driver's serialization size: not written",
                       FindingSource::kReplay, where, -1, copy.dst_address()});
}

void KhrReplay::write_properties(const fbs::CmdWriteAccelerationStructuresProperties& query,
                                 const CommandRef& ref, const ReplayLocation& where) {
    NvReplayContext& c = k_.nv.c_;
    if (!query.acceleration_structures()) return;
    uint32_t index = 0;
    for (uint64_t handle : *query.acceleration_structures()) {
        const uint32_t slot = query.first_query() + index++;
        if (c.options.check_hazards)
            if (auto range = c.memory.object_range(handle)) {
                ++c.report.counts.accesses;
                c.sync.record_access(ref, Access{*range, engine::kStageBuild, kObjectRead, false,
                                                 "pAccelerationStructures[" +
                                                     std::to_string(index - 1) + "]"});
            }
        bool top = false;
        const uint64_t size = engine_object_size(handle, &top);
        if (size == 0) continue;  // nothing the engine can answer for
        Answer a{size, handle, query.query_type(), where};
        if (query.query_type() == VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR ||
            query.query_type() ==
                VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_BOTTOM_LEVEL_POINTERS_KHR) {
            std::string error;
            const std::vector<std::byte> blob =
                engine::serialize_nv_object(c.memory.image(), k_.nv.object(handle)->shadow, &error);
            engine::SerializedHeader h{};
            if (blob.size() >= sizeof h) std::memcpy(&h, blob.data(), sizeof h);
            a.value =
                query.query_type() == VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR
                    ? blob.size()
                    : h.handle_count;
        }
        answers_[{query.query_pool(), slot}] = a;
    }
}

void KhrReplay::query_results(const fbs::QueryPoolResults& results) {
    NvReplayContext& c = k_.nv.c_;
    if (!results.values()) return;
    uint32_t slot = results.first_query();
    for (uint64_t driver : *results.values()) {
        auto it = answers_.find({results.query_pool(), slot});
        const uint32_t query = slot++;
        if (it == answers_.end()) continue;
        const Answer& a = it->second;
        ++c.report.counts.query_answers;
        if (driver == a.value) continue;
        note(kRuleKhrQueryAnswer,
             std::string("query ") + std::to_string(query) + " of pool " +
                 hex(results.query_pool()) + " (" + query_type_name(a.query_type) + " of " +
                 hex(a.acceleration_structure) + "): the driver answered " +
                 std::to_string(driver) + ", the engine " + std::to_string(a.value) +
                 " for its own layout (the layouts differ by design)",
             a.where);
    }
}

void KhrReplay::note(std::string rule, std::string message, const ReplayLocation& where) {
    k_.nv.c_.add_finding(
        {std::move(rule), std::move(message), FindingSource::kReplay, where, -1, 0});
}

}  // namespace clastrace::replay::detail
