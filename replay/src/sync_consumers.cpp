// SPDX-License-Identifier: Apache-2.0
// Consumers of acceleration structures (docs/replay.md, "Consumers"): vkCmdTraceRays* and the
// dispatches and draws whose shaders use ray queries read every structure reachable from what
// they bind (structure_reachability.h), at their shader stages, in the synchronization model;
// a structure destroyed while a consumer that reads it may still run is a finding.
#include "hazard_text.h"
#include "replayer_internal.h"
#include "structure_reachability.h"
#include "sync_consumers.h"
#include "sync_model_internal.h"

#include <clastrace/engine/blas.h>
#include <clastrace/engine/cluster_format.h>

#include <cstring>
#include <set>
#include <tuple>
#include <unordered_set>

namespace clastrace::replay {

std::vector<HazardAccess> SyncModel::pending_accesses(AddressRange range) const {
    std::vector<HazardAccess> out;
    std::unordered_set<uint64_t> seen;  // (tag, stage) already listed
    State& s = *state_;
    auto consider = [&](const Record& r) {
        if (r.queue == kHostSlot || r.completed || r.tag < s.queues[r.queue].complete) return;
        if (!seen.insert(r.tag * 0x9E3779B97F4A7C15ull ^ r.stage).second) return;
        out.push_back(s.describe(r));
    };
    s.segments.for_each(
        [&](const Segment& seg, uint64_t, uint64_t) {
            if (seg.write) consider(*seg.write);
            for (const Record& r : seg.reads) consider(r);
        },
        range.begin, range.end);
    return out;
}

namespace detail {

const char* trace_rays_entry_point(const fbs::CmdTraceRays& rays) {
    static const char* const kEntryPoints[] = {"vkCmdTraceRaysKHR", "vkCmdTraceRaysIndirectKHR",
                                               "vkCmdTraceRaysIndirect2KHR", "vkCmdTraceRaysNV"};
    if (rays.entry_point())
        for (const char* name : kEntryPoints)
            if (rays.entry_point()->str() == name) return name;
    return "vkCmdTraceRaysKHR";
}

namespace {

constexpr uint64_t kTraceRaysIndirectBytes = 12;    // VkTraceRaysIndirectCommandKHR
constexpr uint64_t kTraceRaysIndirect2Bytes = 104;  // VkTraceRaysIndirectCommand2KHR
constexpr const char* kSbtNames[] = {"raygen", "miss", "hit", "callable"};

// Where the consumer found the structure. Sources 3 and 4 keep the value's byte offset in
// array_element (docs/trace-format.md): in the push constants, or from the offset of the buffer
// descriptor bound at set and binding.
std::string binding_name(const fbs::AccelerationStructureBinding& b, size_t index) {
    const std::string set_binding =
        "set " + std::to_string(b.set()) + ", binding " + std::to_string(b.binding());
    const std::string byte = "address at byte " + std::to_string(b.array_element());
    std::string where;
    switch (b.source()) {
    case 0:
    case 1:
    case 2: where = set_binding + "[" + std::to_string(b.array_element()) + "]"; break;
    case 3: where = byte + " of the push constants"; break;
    case 4: where = byte + " of the buffer at " + set_binding; break;
    default: where = "unknown source"; break;
    }
    return std::string(kConsumerField) + std::to_string(index) + "] (" + where + ")";
}

}  // namespace

// The closure's lookups: a structure's bytes as the model sees them, and a cluster bottom level
// in the engine's bytes (captured addresses translated to where the engine rebuilt it).
std::optional<AddressRange> Replay::structure_range(uint64_t handle) const {
    return memory_.object_range(handle);
}

std::optional<ClusterBottomLevel> Replay::cluster_bottom_level(uint64_t address) const {
    if (auto it = translation_.rebuilt_at.find(address); it != translation_.rebuilt_at.end())
        address = it->second;
    const engine::MemoryImage& image = memory_.image();
    try {
        const auto header = image.read<engine::BottomLevelHeader>(address, {"reachability", -1});
        if (header.magic != engine::kObjectMagic ||
            header.object_type != uint8_t(engine::ObjectType::kClustersBottomLevel))
            return std::nullopt;
        ClusterBottomLevel blas;
        blas.range = {address, address + header.object_size};
        // Explicit destinations: the driver's object may fill the room its build wrote.
        if (std::optional<AddressRange> span = memory_.cluster_blas_span(address))
            blas.range.end = std::max(blas.range.end, span->end);
        for (uint32_t i = 0; i < header.reference_count; ++i) {
            const auto reference = image.read<engine::ClusterReference>(
                address + header.references_offset + uint64_t(i) * sizeof(engine::ClusterReference),
                {"reachability", -1});
            const auto clas =
                image.read<engine::ObjectHeader>(reference.clas_address, {"reachability", -1});
            if (clas.magic != engine::kObjectMagic) continue;
            blas.clusters.push_back(
                {reference.reference_index,
                 {reference.clas_address, reference.clas_address + clas.object_size}});
        }
        return blas;
    } catch (const engine::MemoryFault&) {
        return std::nullopt;
    }
}

// Records outside command buffers that the consumers' bookkeeping watches; the families in
// replayer*.cpp handle them too.
void Replay::on_consumer_bookkeeping(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::AccelerationStructureCreate: {
        const auto* c = r.body_as_AccelerationStructureCreate();
        uint64_t reference = c->device_address();
        if (reference == 0 && c->api() == 1)  // a KHR address never queried: where it lives
            if (auto range = memory_.buffer_range(c->buffer(), c->offset(), c->size()))
                reference = range->begin;
        reachability_.on_created(c->acceleration_structure(), reference);
        structure_api_[c->acceleration_structure()] = c->api();
        break;
    }
    case fbs::RecordBody::AccelerationStructureDestroy: {
        const uint64_t handle = r.body_as_AccelerationStructureDestroy()->acceleration_structure();
        const bool nv = structure_api_[handle] == 0;
        if (auto range = memory_.object_range(handle))
            check_commands_done(
                *range,
                nv ? "vkDestroyAccelerationStructureNV" : "vkDestroyAccelerationStructureKHR",
                nv ? "VUID-vkDestroyAccelerationStructureNV-accelerationStructure-03752"
                   : "VUID-vkDestroyAccelerationStructureKHR-accelerationStructure-02442",
                "acceleration structure " + hex(handle) + " is destroyed");
        reachability_.on_destroyed(handle);
        structure_api_.erase(handle);
        break;
    }
    case fbs::RecordBody::BufferDestroy: {
        const uint64_t buffer = r.body_as_BufferDestroy()->buffer();
        if (auto range = memory_.buffer_range(buffer, 0, kWholeSize))
            check_commands_done(*range, "vkDestroyBuffer", "VUID-vkDestroyBuffer-buffer-00922",
                                "buffer " + hex(buffer) + " is destroyed");
        break;
    }
    case fbs::RecordBody::MemoryFree: {
        // Every byte of the allocation, whichever buffers (live or destroyed) reached it.
        const uint64_t memory = r.body_as_MemoryFree()->memory();
        if (auto range = memory_.memory_range(memory))
            check_commands_done(*range, "vkFreeMemory", "VUID-vkFreeMemory-memory-00677",
                                "memory " + hex(memory) + " is freed");
        break;
    }
    case fbs::RecordBody::QueuePresent:
        frames_.on_boundary(r.body_as_QueuePresent()->frame(), next_submission_);
        break;
    case fbs::RecordBody::PreRangeState: {
        // A frame range's prelude (format 1.5): its submission belongs to no frame.
        const auto* state = r.body_as_PreRangeState();
        pre_range_ = PreRangeInfo{state->before_frame(), state->prelude_submission()};
        frames_.on_pre_range(uint32_t(state->prelude_submission()));
        break;
    }
    case fbs::RecordBody::FrameBoundary: {
        // A headless program's frame-end mark (VK_FRAME_BOUNDARY_FRAME_END_BIT_EXT), written after
        // the QueueSubmit that carried it: it ends its frame as a present does.
        const auto* mark = r.body_as_FrameBoundary();
        if (mark->flags() & 1u) frames_.on_boundary(mark->frame(), next_submission_);
        break;
    }
    default: break;
    }
}

// A command still pending (no host wait saw it complete) that uses bytes of `range`: the
// destroyed or freed object was in use. One finding per pending command (per place: queue,
// submission, command buffer, command, secondary). Any device access to
// the bytes counts: a build reads its inputs by device address, which names no buffer, but the
// bytes are the buffer's all the same (once destroyed, a sub-allocator hands them on), and a
// structure's own build or copy "refers to" it as much as a ray query does (02442, 03752).
// Accesses the trace only allows (Access::possible) are no use.
void Replay::check_commands_done(const AddressRange& range, const char* call, const char* rule,
                                 const std::string& what_happens) {
    if (!options_.check_hazards) return;
    std::vector<HazardAccess> pending = sync_.pending_accesses(range);
    std::erase_if(pending, [](const HazardAccess& a) { return a.possible; });
    // Keyed on the whole place: two command buffers of one submission, or two secondaries of
    // one vkCmdExecuteCommands, are two pending commands.
    std::set<std::tuple<QueueId, decltype(command_place_key(CommandRef{}))>> told;
    for (const HazardAccess& a : pending) {
        const CommandRef& c = a.command;
        if (!told.emplace(a.queue, command_place_key(c)).second) continue;
        ReplayLocation where;
        where.sequence = sequence_;
        where.submission = next_submission_;
        where.name = call;
        add_finding({rule,
                     what_happens + " while " +
                         command_place_text(c, a.queue, frames_.frame_of(c.submission)) +
                         ", which " + (a.is_write ? "writes" : "reads") + " it through " + a.field +
                         " at " + stage_names(a.stage) + " / " + access_names(a.access) +
                         ", has not completed: no fence wait or idle wait saw that submission "
                         "finish. Wait for its fence (vkWaitForFences) before " +
                         call + ", or call it a frame in flight later.",
                     FindingSource::kReplay, where, -1, range.begin});
    }
}

// Every structure each binding reaches is read with ACCELERATION_STRUCTURE_READ in each of
// `stages` (one access per stage: a barrier must cover each stage that reads).
void Replay::consumer_reads(const CommandRef& ref, const ConsumerBindings* bindings,
                            StageMask stages, const ReplayLocation& where) {
    if (!options_.check_consumers || !bindings) return;
    check_consumer_structures_built(bindings, where);
    if (!options_.check_hazards) return;
    for (size_t i = 0; i < bindings->size(); ++i) {
        const fbs::AccelerationStructureBinding* b =
            bindings->Get(static_cast<flatbuffers::uoffset_t>(i));
        for (const ReachedStructure& s :
             reachability_.reach(b->acceleration_structure(), b->address(), binding_name(*b, i)))
            for (StageMask m = stages; m; m &= m - 1) {
                ++report_.counts.accesses;
                sync_.record_access(ref, Access{s.range, m & (~m + 1),
                                                VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR,
                                                false, s.path});
            }
    }
}

void Replay::trace_rays(const fbs::CmdTraceRays& rays, const CommandRef& ref,
                        const ReplayLocation& where) {
    lay_in_snapshots(rays.inputs(), where);
    const StageMask stage = VK_PIPELINE_STAGE_2_RAY_TRACING_SHADER_BIT_KHR;
    if (rays.indirect_address() != 0) {
        const bool whole_struct =
            rays.entry_point() && rays.entry_point()->str() == "vkCmdTraceRaysIndirect2KHR";
        const uint64_t size = whole_struct ? kTraceRaysIndirect2Bytes : kTraceRaysIndirectBytes;
        feed(ref, {rays.indirect_address(), rays.indirect_address() + size},
             VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT, VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT, false,
             "indirectDeviceAddress");
    }
    if (const auto* tables = rays.shader_binding_tables())
        for (size_t i = 0; i < tables->size() && i < std::size(kSbtNames); ++i) {
            const fbs::StridedDeviceAddressRegion* t =
                tables->Get(static_cast<flatbuffers::uoffset_t>(i));
            if (t->device_address() != 0 && t->size() != 0)
                feed(ref, {t->device_address(), t->device_address() + t->size()}, stage,
                     VK_ACCESS_2_SHADER_BINDING_TABLE_READ_BIT_KHR, false,
                     std::string("shader binding table (") + kSbtNames[i] + ")");
        }
    consumer_reads(ref, rays.acceleration_structures(), stage, where);
}

// After vkCmdBuildAccelerationStructureNV: a top level's references are those its instance
// buffer held when it was built.
void Replay::note_top_level_build(const fbs::CmdBuildAccelerationStructureNV& build,
                                  const ReplayLocation& where) {
    const fbs::AccelerationStructureInfoNV* info = build.info();
    if (!info || info->type() != VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV) return;
    std::vector<uint8_t> bytes;
    auto range = memory_.buffer_range(build.instance_data(), build.instance_offset(),
                                      uint64_t(info->instance_count()) * kInstanceBytes);
    if (!range || !memory_.read(range->begin, range->end - range->begin, &bytes)) bytes.clear();
    reachability_.on_top_level_built(build.dst(),
                                     packed_instance_references(bytes, info->instance_count()));
    check_instances_built(build.dst(), where);
}

// The references of a KHR top level's instances as the build reads them: packed instances at
// data + primitiveOffset, or (arrayOfPointers) an array of 8-byte addresses of instances.
std::vector<uint64_t> Replay::khr_instance_references(const fbs::GeometryInstancesKHR& instances,
                                                      const fbs::BuildRangeInfoKHR& range) const {
    const uint64_t at = instances.data() + range.primitive_offset();
    const uint32_t count = range.primitive_count();
    std::vector<uint8_t> bytes;
    if (!instances.array_of_pointers()) {
        if (!memory_.read(at, uint64_t(count) * kInstanceBytes, &bytes)) return {};
        return packed_instance_references(bytes, count);
    }
    std::vector<uint64_t> out;
    if (!memory_.read(at, uint64_t(count) * 8, &bytes)) return out;
    std::vector<uint8_t> reference;
    for (uint32_t i = 0; i < count; ++i) {
        uint64_t pointer = 0;
        std::memcpy(&pointer, bytes.data() + uint64_t(i) * 8, 8);
        uint64_t value = 0;
        if (pointer && memory_.read(pointer + kInstanceReferenceOffset, 8, &reference))
            std::memcpy(&value, reference.data(), 8);
        out.push_back(value);
    }
    return out;
}

// After vkCmdBuildAccelerationStructuresKHR (or its indirect form): each top-level info's
// references, read from the instances in replay memory. The build (KhrReplay::build) laid the
// command's input snapshots in already: laying them in again would count them twice.
void Replay::note_khr_top_level_builds(const fbs::CmdBuildAccelerationStructuresKHR& build,
                                       const ReplayLocation& where) {
    if (!build.infos()) return;
    for (const fbs::AccelerationStructureBuildInfoKHR* info : *build.infos()) {
        if (info->type() != VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR || !info->geometries() ||
            info->geometries()->size() == 0 || !info->ranges() || info->ranges()->size() == 0)
            continue;
        const fbs::GeometryKHR* geometry = info->geometries()->Get(0);
        if (geometry->geometry_type() != VK_GEOMETRY_TYPE_INSTANCES_KHR || !geometry->instances())
            continue;
        reachability_.on_top_level_built(info->dst(),
                                         khr_instance_references(*geometry->instances(),
                                                                 *info->ranges()->Get(0)));
        check_instances_built(info->dst(), where);
    }
}

}  // namespace detail
}  // namespace clastrace::replay
