// SPDX-License-Identifier: Apache-2.0
// Pipeline barriers and events: their dependencies, as the synchronization model takes them.
#include "replayer_internal.h"

namespace clastrace::replay::detail {

void Replay::barrier(const fbs::Record& record, const CommandRef& ref) {
    ++report_.counts.barriers;
    if (!options_.check_hazards) return;
    std::vector<MemoryBarrier> global;
    switch (record.body_type()) {
    case fbs::RecordBody::CmdPipelineBarrier: {
        const fbs::CmdPipelineBarrier* b = record.body_as_CmdPipelineBarrier();
        std::vector<BufferBarrier> buffers = buffer_barriers(b->dependency(), &global);
        if (b->version() == 1 && global.empty() && buffers.empty())
            global.push_back(
                execution_barrier_v1(static_cast<VkPipelineStageFlags>(b->src_stage_mask()),
                                     static_cast<VkPipelineStageFlags>(b->dst_stage_mask())));
        sync_.pipeline_barrier(ref,
                               DependencyInfo{global, buffers,
                                              b->dependency() ? b->dependency()->dependency_flags()
                                                              : 0});
        break;
    }
    case fbs::RecordBody::CmdSetEvent: {
        const fbs::CmdSetEvent* e = record.body_as_CmdSetEvent();
        if (e->version() == 1 || !e->dependency()) {
            sync_.set_event_v1(ref, e->event(), static_cast<VkPipelineStageFlags>(e->stage_mask()));
        } else {
            std::vector<BufferBarrier> buffers = buffer_barriers(e->dependency(), &global);
            sync_.set_event(ref, e->event(),
                            DependencyInfo{global, buffers, e->dependency()->dependency_flags()});
        }
        break;
    }
    case fbs::RecordBody::CmdResetEvent:
        sync_.reset_event(ref, record.body_as_CmdResetEvent()->event());
        break;
    case fbs::RecordBody::CmdWaitEvents: {
        const fbs::CmdWaitEvents* w = record.body_as_CmdWaitEvents();
        if (!w->events()) break;
        std::vector<uint64_t> events(w->events()->begin(), w->events()->end());
        const auto* deps = w->dependencies();
        if (w->version() == 1 || !deps || deps->size() != events.size()) {
            std::vector<BufferBarrier> buffers =
                buffer_barriers(deps && deps->size() ? deps->Get(0) : nullptr, &global);
            if (global.empty() && buffers.empty())
                global.push_back(
                    execution_barrier_v1(static_cast<VkPipelineStageFlags>(w->src_stage_mask()),
                                         static_cast<VkPipelineStageFlags>(w->dst_stage_mask())));
            sync_.wait_events(ref, events, DependencyInfo{global, buffers, 0});
        } else {
            // vkCmdWaitEvents2: one VkDependencyInfo per event.
            for (size_t i = 0; i < events.size(); ++i) {
                global.clear();
                std::vector<BufferBarrier> buffers =
                    buffer_barriers(deps->Get(static_cast<flatbuffers::uoffset_t>(i)), &global);
                sync_.wait_events(ref, std::span<const uint64_t>(&events[i], 1),
                                  DependencyInfo{global, buffers, 0});
            }
        }
        break;
    }
    default: break;
    }
}

std::vector<BufferBarrier> Replay::buffer_barriers(const fbs::Dependency* dependency,
                                                   std::vector<MemoryBarrier>* global) {
    std::vector<BufferBarrier> out;
    if (!dependency) return out;
    if (dependency->memory_barriers()) {
        for (const fbs::MemoryBarrier* b : *dependency->memory_barriers())
            global->push_back({b->src_stage_mask(), b->src_access_mask(), b->dst_stage_mask(),
                               b->dst_access_mask()});
    }
    if (dependency->buffer_barriers()) {
        for (const fbs::BufferMemoryBarrier* b : *dependency->buffer_barriers()) {
            MemoryBarrier masks{b->src_stage_mask(), b->src_access_mask(), b->dst_stage_mask(),
                                b->dst_access_mask()};
            if (auto range = memory_.buffer_range(b->buffer(), b->offset(), b->size())) {
                out.push_back({masks, *range});
            } else {
                // A buffer the trace never bound: keep the execution dependency only.
                global->push_back({masks.src_stages, 0, masks.dst_stages, 0});
            }
        }
    }
    return out;
}

}  // namespace clastrace::replay::detail
