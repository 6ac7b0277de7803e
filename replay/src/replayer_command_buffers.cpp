// SPDX-License-Identifier: Apache-2.0
// Command buffers: recording (and restating) their commands, forgetting them on reset or past
// the memory limit, and executing one at submission, secondaries inline.
#include "replayer_internal.h"

namespace clastrace::replay::detail {

namespace {

const char* command_name(fbs::RecordBody kind) {
    switch (kind) {
    case fbs::RecordBody::CmdPipelineBarrier: return "vkCmdPipelineBarrier";
    case fbs::RecordBody::CmdSetEvent: return "vkCmdSetEvent";
    case fbs::RecordBody::CmdResetEvent: return "vkCmdResetEvent";
    case fbs::RecordBody::CmdWaitEvents: return "vkCmdWaitEvents";
    case fbs::RecordBody::CmdCopyBuffer: return "vkCmdCopyBuffer";
    case fbs::RecordBody::CmdFillBuffer: return "vkCmdFillBuffer";
    case fbs::RecordBody::CmdUpdateBuffer: return "vkCmdUpdateBuffer";
    case fbs::RecordBody::CmdDispatch: return "vkCmdDispatch";
    case fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect:
        return "vkCmdBuildClusterAccelerationStructureIndirectNV";
    case fbs::RecordBody::CmdBuildAccelerationStructureNV:
        return "vkCmdBuildAccelerationStructureNV";
    case fbs::RecordBody::CmdCopyMemoryToAccelerationStructure:
        return "vkCmdCopyMemoryToAccelerationStructureKHR";
    case fbs::RecordBody::GpuTimestamp: return "vkCmdWriteTimestamp";
    case fbs::RecordBody::DebugLabel: return "vkCmdDebugUtilsLabelEXT";
    case fbs::RecordBody::CmdExecuteCommands: return "vkCmdExecuteCommands";
    case fbs::RecordBody::CmdDraw: return "vkCmdDraw";
    case fbs::RecordBody::CmdCopyAccelerationStructureToMemory:
        return "vkCmdCopyAccelerationStructureToMemoryKHR";
    case fbs::RecordBody::CmdBuildAccelerationStructuresKHR:
        return "vkCmdBuildAccelerationStructuresKHR";
    default: return "command";
    }
}

// A draw's entry point as a static string (findings keep the name after the recording is gone).
const char* draw_entry_point(const fbs::CmdDraw& draw) {
    static const char* const kDraws[] = {"vkCmdDraw",
                                         "vkCmdDrawIndexed",
                                         "vkCmdDrawIndirect",
                                         "vkCmdDrawIndexedIndirect",
                                         "vkCmdDrawIndirectCount",
                                         "vkCmdDrawIndexedIndirectCount",
                                         "vkCmdDrawMeshTasksEXT",
                                         "vkCmdDrawMeshTasksIndirectEXT",
                                         "vkCmdDrawMeshTasksIndirectCountEXT",
                                         "vkCmdDrawMeshTasksNV",
                                         "vkCmdDrawMeshTasksIndirectNV",
                                         "vkCmdDrawMeshTasksIndirectCountNV"};
    if (draw.entry_point())
        for (const char* name : kDraws)
            if (draw.entry_point()->str() == name) return name;
    return "vkCmdDraw";
}

const char* command_name(const fbs::Record& record) {
    if (const fbs::CmdDraw* draw = record.body_as_CmdDraw()) return draw_entry_point(*draw);
    if (const auto* b = record.body_as_CmdBuildAccelerationStructuresKHR())
        return b->indirect() ? "vkCmdBuildAccelerationStructuresIndirectKHR"
                             : "vkCmdBuildAccelerationStructuresKHR";
    if (const auto* c = record.body_as_CmdCopyAccelerationStructure())
        return c->api() == 0 ? "vkCmdCopyAccelerationStructureNV"
                             : "vkCmdCopyAccelerationStructureKHR";
    if (const auto* q = record.body_as_CmdWriteAccelerationStructuresProperties())
        return q->api() == 0 ? "vkCmdWriteAccelerationStructuresPropertiesNV"
                             : "vkCmdWriteAccelerationStructuresPropertiesKHR";
    if (const fbs::CmdTraceRays* rays = record.body_as_CmdTraceRays())
        return trace_rays_entry_point(*rays);
    if (const auto* b = record.body_as_CmdPipelineBarrier())
        return b->version() == 2 ? "vkCmdPipelineBarrier2" : "vkCmdPipelineBarrier";
    if (const auto* e = record.body_as_CmdSetEvent())
        return e->version() == 2 ? "vkCmdSetEvent2" : "vkCmdSetEvent";
    if (const auto* w = record.body_as_CmdWaitEvents())
        return w->version() == 2 ? "vkCmdWaitEvents2" : "vkCmdWaitEvents";
    return command_name(record.body_type());
}

uint64_t command_buffer_of(const fbs::Record& r) {
    switch (r.body_type()) {
    case fbs::RecordBody::CmdPipelineBarrier:
        return r.body_as_CmdPipelineBarrier()->command_buffer();
    case fbs::RecordBody::CmdSetEvent: return r.body_as_CmdSetEvent()->command_buffer();
    case fbs::RecordBody::CmdResetEvent: return r.body_as_CmdResetEvent()->command_buffer();
    case fbs::RecordBody::CmdWaitEvents: return r.body_as_CmdWaitEvents()->command_buffer();
    case fbs::RecordBody::CmdCopyBuffer: return r.body_as_CmdCopyBuffer()->command_buffer();
    case fbs::RecordBody::CmdFillBuffer: return r.body_as_CmdFillBuffer()->command_buffer();
    case fbs::RecordBody::CmdUpdateBuffer: return r.body_as_CmdUpdateBuffer()->command_buffer();
    case fbs::RecordBody::CmdDispatch: return r.body_as_CmdDispatch()->command_buffer();
    case fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect:
        return r.body_as_CmdBuildClusterAccelerationStructureIndirect()->command_buffer();
    case fbs::RecordBody::CmdBuildAccelerationStructureNV:
        return r.body_as_CmdBuildAccelerationStructureNV()->command_buffer();
    case fbs::RecordBody::CmdCopyMemoryToAccelerationStructure:
        return r.body_as_CmdCopyMemoryToAccelerationStructure()->command_buffer();
    case fbs::RecordBody::GpuTimestamp: return r.body_as_GpuTimestamp()->command_buffer();
    case fbs::RecordBody::DebugLabel: return r.body_as_DebugLabel()->command_buffer();
    case fbs::RecordBody::CmdExecuteCommands:
        return r.body_as_CmdExecuteCommands()->command_buffer();
    case fbs::RecordBody::CmdDraw: return r.body_as_CmdDraw()->command_buffer();
    case fbs::RecordBody::CmdBuildAccelerationStructuresKHR:
        return r.body_as_CmdBuildAccelerationStructuresKHR()->command_buffer();
    case fbs::RecordBody::CmdCopyAccelerationStructure:
        return r.body_as_CmdCopyAccelerationStructure()->command_buffer();
    case fbs::RecordBody::CmdCopyAccelerationStructureToMemory:
        return r.body_as_CmdCopyAccelerationStructureToMemory()->command_buffer();
    case fbs::RecordBody::CmdWriteAccelerationStructuresProperties:
        return r.body_as_CmdWriteAccelerationStructuresProperties()->command_buffer();
    case fbs::RecordBody::CmdTraceRays: return r.body_as_CmdTraceRays()->command_buffer();
    default: return 0;
    }
}

}  // namespace

// Command buffers' lifetimes: a begin starts a recording (or a restatement of one), a reset
// forgets it.
bool Replay::on_command_buffer_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::CommandBufferBegin: {
        const fbs::CommandBufferBegin* begin = r.body_as_CommandBufferBegin();
        Recorded& cb = recorded_[begin->command_buffer()];
        if (const uint32_t k = begin->restatement(); k != 0) {
            // Copy k of the recording, for the (k+1)-th execution in the next submission; a
            // hostile index cannot make the list longer than the copies actually written.
            if (k > cb.restated.size() + 1) {
                add_finding(
                    {"CLASTRACE-replay-restatement-out-of-order",
                     "CommandBufferBegin of " + detail::hex(begin->command_buffer()) +
                         " restates execution " + std::to_string(k) + " but only " +
                         std::to_string(cb.restated.size()) +
                         " restatement(s) precede it: its commands are kept as restatement " +
                         std::to_string(cb.restated.size() + 1),
                     FindingSource::kReplay,
                     ReplayLocation{sequence_, next_submission_, 0, 0, begin->command_buffer(),
                                    "vkBeginCommandBuffer"},
                     -1, 0});
            }
            const size_t slot = std::min<size_t>(k, cb.restated.size() + 1);
            if (slot > cb.restated.size()) cb.restated.emplace_back();
            cb.restated[slot - 1].clear();
            cb.filling = static_cast<uint32_t>(slot);
            break;
        }
        drop_recorded(cb);
        recycle(cb);
        Commands kept = std::move(cb.commands);  // (its room, for the commands to come)
        kept.clear();
        cb = Recorded{};
        cb.commands = std::move(kept);
        dropped_.erase(begin->command_buffer());
        cb.one_time = begin->flags() & VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
        cb.secondary = begin->level() == 1;
        break;
    }
    case fbs::RecordBody::CommandBufferReset:
        reset_command_buffers(*r.body_as_CommandBufferReset());
        break;
    default: return false;
    }
    return true;
}

void Replay::reset_command_buffers(const fbs::CommandBufferReset& reset) {
    if (reset.command_buffer() != 0) {
        forget_recorded(reset.command_buffer());
        if (reset.command_pool() != 0)
            pool_members_[reset.command_pool()].insert(reset.command_buffer());
        return;
    }
    if (reset.command_pool() == 0) return;
    auto members = pool_members_.find(reset.command_pool());
    if (members == pool_members_.end()) {
        if (!pools_noted_.insert(reset.command_pool()).second)
            return;  // a pool reset every frame: noted once
        ReplayLocation where;
        where.submission = next_submission_;
        where.name = "vkResetCommandPool";
        report_.not_replayed.push_back(
            {where,
             "vkResetCommandPool(" + detail::hex(reset.command_pool()) +
                 "): the trace does not say which command buffers the pool holds; "
                 "a buffer submitted again without being re-recorded replays its old commands"});
        return;
    }
    for (uint64_t cb : members->second) forget_recorded(cb);
}

// A command: appended to the recording (or restatement) its command buffer is filling.
void Replay::record_command(const traces::RecordView& view) {
    const fbs::Record& r = *view.record;
    if (uint64_t cb = command_buffer_of(r)) {
        Recorded& recorded = recorded_[cb];
        std::vector<uint8_t> bytes;
        if (!spare_command_bytes_.empty()) {
            bytes = std::move(spare_command_bytes_.back());
            spare_command_bytes_.pop_back();
        }
        bytes.assign(view.bytes, view.bytes + view.size);
        const RecordedCommand& command = recorded.target().emplace_back(
            RecordedCommand{std::move(bytes), take_answers(recorded)});
        recorded.bytes += view.size;
        recorded_bytes_ += view.size;
        if (ahead_runs_)  // if not started yet; the answers are the command's, or still staged
            start_cluster_run(view,
                              command.answers.empty() && staged_answers_
                                  ? std::span<const SnapshotAnswer>(*staged_answers_)
                                  : std::span<const SnapshotAnswer>(command.answers),
                              stream_index_, false);
    }
}

void Replay::recycle(Recorded& cb) {
    // Last command first, so the next recording's first command takes the first one's buffer.
    auto take = [&](Commands& commands) {
        for (auto c = commands.rbegin(); c != commands.rend(); ++c) {
            if (spare_command_bytes_.size() >= kSpareCommandBuffers) return;
            if (c->bytes.capacity() != 0 && c->bytes.capacity() <= kSpareCommandBufferBytes)
                spare_command_bytes_.push_back(std::move(c->bytes));
        }
    };
    for (auto r = cb.restated.rbegin(); r != cb.restated.rend(); ++r) take(*r);
    take(cb.commands);
}

SnapshotAnswers Replay::take_answers(Recorded& recorded) {
    SnapshotAnswers none{SnapshotAnswers::allocator_type(nullptr)};
    if (!staged_answers_ || staged_answers_->empty()) return none;
    uint64_t bytes = 0;
    for (const SnapshotAnswer& a : *staged_answers_) bytes += a.second->size();
    if (answer_bytes_ + bytes > kMaxAnswerBytes) return none;
    answer_bytes_ += bytes;
    recorded.answer_bytes += bytes;
    return std::move(*staged_answers_);
}

// Command buffers stay recorded after submission because they may be submitted again;
// captures rarely say when one is freed, so past the limit the least recently submitted go.
void Replay::limit_recorded() {
    if (recorded_bytes_ <= options_.max_recorded_bytes) return;
    std::vector<std::pair<uint64_t, uint64_t>> submitted;  // (submitted, handle)
    for (const auto& [handle, cb] : recorded_)
        if (cb.submitted) submitted.emplace_back(cb.submitted, handle);
    std::sort(submitted.begin(), submitted.end());
    for (const auto& [when, handle] : submitted) {
        if (recorded_bytes_ <= options_.max_recorded_bytes / 2) break;
        drop_recorded(recorded_[handle]);
        recorded_.erase(handle);
        if (dropped_.size() < (1u << 16)) dropped_.insert(handle);
    }
}

void Replay::run_command_buffer(uint64_t handle, QueueId queue, uint32_t submission,
                                uint32_t cb_index, const CommandRef* inside) {
    const char* where_name = inside ? "vkCmdExecuteCommands" : "vkQueueSubmit";
    auto location_here = [&] {
        ReplayLocation where{sequence_, submission, cb_index, 0, handle, where_name};
        where.queue = queue;
        if (inside) {
            where.command_buffer_handle = inside->command_buffer_handle;
            where.command = inside->command;
            where.secondary_handle = handle;
            where.secondary = inside->secondary;
        }
        return where;
    };
    auto it = recorded_.find(handle);
    if (it == recorded_.end()) {
        if (dropped_.count(handle))
            add_finding(
                {"CLASTRACE-replay-command-buffer-dropped",
                 "command buffer " + detail::hex(handle) +
                     " is submitted again, but its commands were dropped to keep the replay within "
                     "ReplayOptions::max_recorded_bytes (" +
                     std::to_string(options_.max_recorded_bytes) + "): not replayed",
                 FindingSource::kReplay, location_here(), -1, 0});
        else  // Reset (buffer or pool), never begun in the trace, or a one-time buffer submitted again.
            add_finding({"CLASTRACE-replay-command-buffer-not-recorded",
                         "command buffer " + detail::hex(handle) +
                             " holds no recorded commands (reset, never begun in the trace, or "
                             "ONE_TIME_SUBMIT and already submitted): nothing of it is replayed",
                         FindingSource::kReplay, location_here(), -1, 0});
        return;
    }
    Recorded& recorded = it->second;
    recorded.submitted = uint64_t(submission) + 1;
    const uint32_t execution = executions_[handle]++;
    const Commands& commands = recorded.copy_for(execution);
    uint32_t command = 0;
    for (const RecordedCommand& recorded_command : commands) {
        const std::vector<uint8_t>& bytes = recorded_command.bytes;
        const fbs::Record* record = flatbuffers::GetRoot<fbs::Record>(bytes.data());
        const uint64_t sequence = sequence_++;
        CommandRef ref{submission, cb_index, handle, command, command_name(*record)};
        if (inside) {
            ref = *inside;
            ref.name = command_name(*record);
            ref.secondary_handle = handle;
            ref.secondary_command = command;
        }
        command_bytes_ = &bytes;  // build_clusters finds the command's run ahead by its bytes
        const CurrentAnswers record_answers =
            std::exchange(answers_, {&recorded_command.answers, 0});
        replay_command(*record, ref, location(ref, sequence, queue),
                       selected(sequence, submission));
        answers_ = record_answers;  // of what runs this buffer: a record, or a command
        command_bytes_ = nullptr;
        // The secondaries' commands get their own sequence numbers and are selected (--ops) one
        // by one, whether or not the execute command itself is.
        if (record->body_type() == fbs::RecordBody::CmdExecuteCommands) {
            if (inside) {
                if (selected(sequence, submission))
                    report_.not_replayed.push_back(
                        {location(ref, sequence, queue),
                         "vkCmdExecuteCommands inside a secondary command buffer "
                         "(VK_EXT_nested_command_buffer): the nested secondaries are not "
                         "replayed"});
            } else {
                execute_secondaries(*record->body_as_CmdExecuteCommands(), ref, queue);
            }
        }
        // The layer's timestamps are no command of the application's: the next command keeps
        // the index the application gave it (a trace older than format 1.9 numbered them).
        command += record->body_type() != fbs::RecordBody::GpuTimestamp ||
                   reader_.timestamps_take_command_indices();
    }
    if (!inside && recorded.one_time) forget_recorded(handle);
}

// The secondaries run inline, in list order, as part of the primary's command-buffer order:
// the synchronization model sees their commands between the primary's commands before and
// after the vkCmdExecuteCommands.
void Replay::execute_secondaries(const fbs::CmdExecuteCommands& execute, const CommandRef& ref,
                                 QueueId queue) {
    if (!execute.secondaries()) return;
    uint32_t index = 0;
    for (uint64_t secondary : *execute.secondaries()) {
        CommandRef inside = ref;
        inside.secondary = index++;
        auto it = recorded_.find(secondary);
        if (it != recorded_.end() && !it->second.secondary)
            add_finding({"VUID-vkCmdExecuteCommands-pCommandBuffers-00088",
                         "pCommandBuffers[" + std::to_string(inside.secondary) + "] (" +
                             detail::hex(secondary) +
                             ") was begun as a primary command buffer (CommandBufferBegin level "
                             "0): it is replayed "
                             "inline all the same",
                         FindingSource::kReplay, location(ref, sequence_, queue), -1, 0});
        run_command_buffer(secondary, queue, ref.submission, ref.command_buffer, &inside);
    }
}

}  // namespace clastrace::replay::detail
