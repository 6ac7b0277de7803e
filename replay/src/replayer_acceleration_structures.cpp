// SPDX-License-Identifier: Apache-2.0
// Acceleration structures: their objects and size queries, the builds and deserializations
// that write them (cluster_command.cpp, nv_command.cpp do the work), and the captured ray checks.
#include "replayer_internal.h"

#include <tbb/task_arena.h>

namespace clastrace::replay::detail {

// Acceleration-structure objects (create, bind, destroy) and the size queries a build
// is checked against.
bool Replay::on_acceleration_structure_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::AccelerationStructureCreate: {
        const auto* c = r.body_as_AccelerationStructureCreate();
        memory_.create_object(c->acceleration_structure(), c->buffer(), c->offset(), c->size(), 0);
        nv_.on_create(*c);
        khr_.on_create(*c);
        break;
    }
    case fbs::RecordBody::AccelerationStructureMemoryRequirementsNV: {
        const auto* q = r.body_as_AccelerationStructureMemoryRequirementsNV();
        if (q->type() == VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_OBJECT_NV)
            memory_.object_requirement(q->acceleration_structure(), q->size());
        nv_.on_requirement(*q);
        break;
    }
    case fbs::RecordBody::AccelerationStructureBindMemory: {
        const auto* b = r.body_as_AccelerationStructureBindMemory();
        memory_.bind_object(b->acceleration_structure(), b->memory(), b->memory_offset());
        nv_.on_bind(*b);
        break;
    }
    case fbs::RecordBody::AccelerationStructureDestroy:
        memory_.destroy_object(r.body_as_AccelerationStructureDestroy()->acceleration_structure());
        break;
    case fbs::RecordBody::GetClusterBuildSizes: {
        cluster_queries_.on_query(*r.body_as_GetClusterBuildSizes());
        break;
    }
    default: return false;
    }
    return true;
}

// A cluster build runs on the engine with its count checked against the largest
// vkGetClusterAccelerationStructureBuildSizesNV query for its op type and mode, and its
// scratch and implicit ranges sized by the query that matches its input
// (cluster_size_queries.h).
void Replay::build_clusters(const fbs::CmdBuildClusterAccelerationStructureIndirect& build,
                            const CommandRef& ref, const ReplayLocation& where) {
    lay_in_snapshots(build.inputs(), where);
    uint32_t queried = 0;
    if (build.input())
        queried =
            cluster_queries_.largest_count(build.input()->op_type(), build.input()->op_mode());
    ClusterCommandContext context{memory_,
                                  directory_,
                                  translation_,
                                  properties_,
                                  options_,
                                  report_,
                                  sync_,
                                  ref,
                                  where,
                                  report_.engine_trace,
                                  [this](ReplayFinding f) { add_finding(std::move(f)); },
                                  [this](uint64_t hash, std::vector<uint8_t>* out) {
                                      return contents(hash, out);
                                  },
                                  observed_execution_,
                                  observed_engine_ns_};
    std::shared_ptr<ClusterRunAhead> ahead;
    if (ahead_runs_ && command_bytes_) ahead = ahead_runs_->take(*command_bytes_);
    context.ahead = ahead.get();
    if (!ahead_runs_) return run_cluster_command(build, queried, cluster_queries_, context);
    // Isolated: waiting in the engine's parallel loop, this thread must not take up a run of a
    // later command (queued on the arena), which would hold up every command after this one.
    tbb::this_task_arena::isolate(
        [&] { run_cluster_command(build, queried, cluster_queries_, context); });
    if (!ahead) return;
    ++(ahead->stood() ? ahead_runs_->counts.stood : ahead_runs_->counts.run_again);
    ahead->release_image();  // a later BLAS run may still lay in what it wrote, kept apart
}
void Replay::build_nv(const fbs::CmdBuildAccelerationStructureNV& b, const CommandRef& ref,
                      const ReplayLocation& where) {
    nv_.build(b, ref, where);  // nv_command.cpp
}

void Replay::copy_to_object(const fbs::CmdCopyMemoryToAccelerationStructure& c,
                            const CommandRef& ref, const ReplayLocation& where) {
    nv_.deserialize(c, ref, where);  // nv_command.cpp
}

// Checks the capture made on the device, compared with the replay's own result.
bool Replay::on_check_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::RayQueryCheck: nv_.ray_check(*r.body_as_RayQueryCheck()); break;
    default: return false;
    }
    return true;
}

}  // namespace clastrace::replay::detail
