// SPDX-License-Identifier: Apache-2.0
// Pre-range state (layer_pre_range.h): per device, the last build or copy of each structure made
// before CLASTRACE_FRAME_RANGE starts, with the bytes it read at execution, written at the start
// of the range as one synthetic submission. Kept per command (one KHR build may build several
// structures): a command is dropped once every structure it produced was rebuilt or destroyed.
#include "layer_pre_range.h"

#include "layer_pre_range_clusters.h"
#include "layer_state.h"

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <tuple>

namespace clastrace::capture {
namespace {

// Replay must see a structure's inputs built before what reads it: cluster-free levels, in this
// order, each in the order the application ran them (an update or copy after its source).
enum class StateLevel { kBottom = 0, kTop = 1 };

struct KeptCommand {
    uint64_t sequence = 0;  // execution order before the range
    StateLevel level = StateLevel::kBottom;
    RecordedCommand command;
    std::set<uint64_t> produced;  // structures this command built or copied into
    std::set<uint64_t> current;   // those of them still holding what it made
    std::set<uint64_t> memories;  // the memory its KHR structures' buffers were bound to
    std::optional<ClusterBuildCapture> capture;
};

using CaptureKey = std::tuple<uint64_t, uint64_t, uint32_t>;  // submission, pause, occurrence

struct PreRangeStore {
    std::mutex mutex;
    std::map<CaptureKey, KeptCommand> kept;
    PreRangeClusterCommands clusters;  // run first in the prelude: a top level may name them
    std::set<uint64_t> submissions;    // before the range, their captures still to come
    // Before the range: submission -> how its completion shows; `waited` those the application
    // saw complete (their captures come from the layer's own threads: the prelude waits for them).
    std::map<uint64_t, PreRangeSubmission> submitted_on;
    std::set<uint64_t> waited;
    std::condition_variable capture_arrived;
    uint64_t next_sequence = 0;
    bool written = false;
    // Prelude commands whose captures had not come when it was written: their key before the
    // range -> the prelude submission and pause id the sink waits for.
    std::map<CaptureKey, std::pair<uint64_t, uint64_t>> forwarded;
    std::map<uint64_t, uint64_t> nv_memory;  // NV structure -> the memory bound to it
};

std::mutex storesMutex;
std::map<const DeviceState*, std::unique_ptr<PreRangeStore>> stores;

PreRangeStore& store_of(const DeviceState& d) {
    std::lock_guard lock(storesMutex);
    auto& s = stores[&d];
    if (!s) s = std::make_unique<PreRangeStore>();
    return *s;
}

bool is_top_level_khr(const KhrBuildInfo& info) {
    return info.info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
}

// The kept form of `pause`'s command: what it produces, at which level. False for a command
// that produces no structure (a copy to memory).
bool describe(const PausePoint& pause, KeptCommand& out) {
    if (pause.build_khr) {
        out.command = *pause.build_khr;
        for (const KhrBuildInfo& info : pause.build_khr->infos) {
            out.produced.insert(handle_id(info.info.dstAccelerationStructure));
            if (is_top_level_khr(info)) out.level = StateLevel::kTop;
        }
    } else if (pause.build_nv) {
        out.command = *pause.build_nv;
        out.produced.insert(pause.build_nv->dst);
        if (pause.build_nv->type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV)
            out.level = StateLevel::kTop;
    } else if (pause.copy_acceleration_structure && !pause.copy_acceleration_structure->to_memory) {
        out.command = *pause.copy_acceleration_structure;
        out.produced.insert(pause.copy_acceleration_structure->dst);
    } else {
        return false;
    }
    return !out.produced.empty();
}

// Structures `command` reads as its source (updates, copies): their producers stay while a
// kept reader needs them.
std::set<uint64_t> sources_of(const RecordedCommand& command) {
    std::set<uint64_t> sources;
    if (const auto* b = std::get_if<BuildAccelerationStructuresKHRCommand>(&command))
        for (const KhrBuildInfo& info : b->infos)
            if (info.info.mode == VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR)
                sources.insert(handle_id(info.info.srcAccelerationStructure));
    if (const auto* n = std::get_if<BuildAccelerationStructureNVCommand>(&command))
        if (n->update) sources.insert(n->src);
    if (const auto* c = std::get_if<CopyAccelerationStructureCommand>(&command))
        sources.insert(c->src);
    return sources;
}

// `structure` no longer holds what older commands made: a command goes once none of its
// structures holds its output and no later kept command reads one of them as its source.
void supersede(PreRangeStore& s, uint64_t structure) {
    for (auto& [key, k] : s.kept) k.current.erase(structure);
    for (auto it = s.kept.begin(); it != s.kept.end();) {
        const KeptCommand& k = it->second;
        const bool read_later = std::any_of(s.kept.begin(), s.kept.end(), [&](const auto& other) {
            if (other.second.sequence <= k.sequence) return false;
            const std::set<uint64_t> sources = sources_of(other.second.command);
            return std::any_of(k.produced.begin(), k.produced.end(),
                               [&](uint64_t p) { return sources.count(p) != 0; });
        });
        it = k.current.empty() && !read_later ? s.kept.erase(it) : std::next(it);
    }
}

uint64_t kept_bytes(const PreRangeStore& s) {
    uint64_t bytes = 0;
    for (const auto& [key, k] : s.kept)
        if (k.capture)
            for (const CapturedRange& r : k.capture->inputs) bytes += r.bytes.size();
    return bytes;
}

uint64_t& pause_id_in(RecordedCommand& command) {
    if (auto* b = std::get_if<BuildAccelerationStructuresKHRCommand>(&command)) return b->pause_id;
    if (auto* n = std::get_if<BuildAccelerationStructureNVCommand>(&command)) return n->pause_id;
    return std::get<CopyAccelerationStructureCommand>(command).pause_id;
}

// Between two prelude commands: everything before complete and visible to everything after.
BarrierCommand full_barrier() {
    BarrierCommand b;
    b.synchronization2 = true;
    MemoryBarrier m;
    m.src_stage = m.dst_stage = VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT;
    m.src_access = VK_ACCESS_2_MEMORY_WRITE_BIT;
    m.dst_access = VK_ACCESS_2_MEMORY_READ_BIT | VK_ACCESS_2_MEMORY_WRITE_BIT;
    b.memory_barriers.push_back(m);
    return b;
}

// The kept commands in the order replay must run them: bottom levels (and their copies) before
// top levels, each level in execution order.
std::vector<KeptCommand*> prelude_order(PreRangeStore& s) {
    std::vector<KeptCommand*> order;
    for (auto& [key, k] : s.kept) order.push_back(&k);
    std::sort(order.begin(), order.end(), [](const KeptCommand* a, const KeptCommand* b) {
        return std::tie(a->level, a->sequence) < std::tie(b->level, b->sequence);
    });
    return order;
}

// The memory a structure lives in (a KHR one through its buffer); 0 when the layer does not
// know it.
uint64_t memory_of_structure(const DeviceState& d, const PreRangeStore& s, uint64_t structure) {
    if (auto nv = s.nv_memory.find(structure); nv != s.nv_memory.end()) return nv->second;
    const KhrStructureStorage storage = khr_structure_storage(d, structure);
    if (!storage.buffer) return 0;
    const std::optional<TrackedBuffer> buffer = d.memory_map.buffer(storage.buffer);
    return buffer ? buffer->memory : 0;
}

// What the prelude holds, said at info level and in its PreRangeState record.
PreRangeStateRecord marker_of(const PreRangeStore& s, const SubmissionRecord& captured,
                              uint64_t index) {
    std::set<uint64_t> structures;
    for (const auto& [key, k] : s.kept) structures.insert(k.current.begin(), k.current.end());
    PreRangeStateRecord marker;
    marker.queue = captured.queue;
    marker.first_frame = layer_config().frame_range.first;
    marker.prelude_submission = index;
    marker.cluster_commands = uint32_t(s.clusters.size());
    marker.structures = uint32_t(structures.size()) + s.clusters.live_objects();
    marker.commands = uint32_t(s.kept.size()) + marker.cluster_commands;
    marker.bytes = kept_bytes(s) + s.clusters.bytes(false);
    size_t to_come = s.clusters.size() - s.clusters.arrived_count();
    for (const auto& [key, k] : s.kept) to_come += !k.capture;
    log_message(LogLevel::kInfo,
                "pre-range state: %u structures from %u commands (%u cluster commands) before "
                "frame %llu, %llu input bytes kept (and %llu bytes of cluster outputs); %zu "
                "captures still to come, which the trace waits for",
                marker.structures, marker.commands, marker.cluster_commands,
                (unsigned long long)marker.first_frame, (unsigned long long)marker.bytes,
                (unsigned long long)s.clusters.bytes(true), to_come);
    return marker;
}

}  // namespace

bool before_frame_range(const DeviceState& d, uint64_t index) {
    const LayerConfig& config = layer_config();
    return config.pre_range_state && d.capturing_now() && config.frame_range.first > 0 &&
           current_frame() < config.frame_range.first && config.submit_range.contains(index);
}

bool produces_pre_range_state(const PausePoint& pause) {
    if (pause.parameters) return writes_cluster_objects(*pause.parameters);
    KeptCommand unused;
    return describe(pause, unused);
}

void note_pre_range_submission(DeviceState& d, const SubmissionRecord& submission,
                               const std::vector<const PausePoint*>& pauses) {
    const uint64_t index = submission.index;
    PreRangeStore& s = store_of(d);
    std::lock_guard lock(s.mutex);
    if (s.written) return;
    s.submissions.insert(index);
    PreRangeSubmission& on = s.submitted_on[index];
    on.queue = submission.queue;
    on.fence = submission.fence;
    if (!submission.batches.empty()) on.last_signals = submission.batches.back().signals;
    for (const PausePoint* pause : pauses) {
        if (pause->parameters) {  // a cluster command, both of whose pauses are read
            if (pause->phase == PausePhase::kBeforeCommand)
                s.clusters.note({index, pause->pause_id, pause->occurrence},
                                ClusterBuildCommand{*pause->parameters, pause->pause_id,
                                                    d.serving});
            continue;
        }
        KeptCommand k;
        if (!describe(*pause, k)) continue;
        for (uint64_t structure : k.produced) supersede(s, structure);
        k.sequence = s.next_sequence++;
        k.current = k.produced;
        for (uint64_t structure : k.produced)
            if (uint64_t memory = memory_of_structure(d, s, structure)) k.memories.insert(memory);
        s.kept[{index, pause->pause_id, pause->occurrence}] = std::move(k);
    }
}

// A capture that came after the prelude was written: it goes to the sink under the prelude's
// submission and pause id, and the sink holds the prelude (and all after it) until it has it.
// False when the prelude no longer wants it (superseded before the prelude was written).
bool forward_late_capture(DeviceState& d, PreRangeStore& s, std::unique_lock<std::mutex>& lock,
                          ClusterBuildCapture& capture) {
    auto it = s.forwarded.find({capture.submission_index, capture.pause_id, capture.occurrence});
    if (it == s.forwarded.end()) return false;
    capture.submission_index = it->second.first;
    capture.pause_id = it->second.second;
    capture.occurrence = 0;
    capture.command_buffer = kPreRangeCommandBuffer;
    s.forwarded.erase(it);
    lock.unlock();
    d.sink->cluster_build_captured(std::move(capture));
    return true;
}

bool take_pre_range_capture(DeviceState& d, ClusterBuildCapture& capture) {
    PreRangeStore& s = store_of(d);
    std::unique_lock lock(s.mutex);
    if (!s.submissions.count(capture.submission_index)) return false;
    if (s.written) {
        forward_late_capture(d, s, lock, capture);
        return true;
    }
    const CaptureKey key{capture.submission_index, capture.pause_id, capture.occurrence};
    if (s.clusters.expects(key)) {
        // Completing a served capture walks its outputs: not under the lock the queue's
        // submissions take.
        lock.unlock();
        prepare_kept_cluster_capture(capture);
        lock.lock();
        if (s.written)  // the prelude was written meanwhile, without it
            forward_late_capture(d, s, lock, capture);
        else
            s.clusters.arrived(key, std::move(capture));
        s.capture_arrived.notify_all();
        return true;
    }
    if (auto it = s.kept.find(key); it != s.kept.end()) it->second.capture = std::move(capture);
    s.capture_arrived.notify_all();
    return true;
}

void note_pre_range_wait(DeviceState& d,
                         const std::function<bool(const PreRangeSubmission&)>& completes) {
    if (!layer_config().pre_range_state || layer_config().frame_range.first == 0) return;
    PreRangeStore& s = store_of(d);
    std::lock_guard lock(s.mutex);
    if (s.written) return;
    // A fence's signal also orders every earlier submission on its queue: newest first.
    std::set<uint64_t> queues_done;
    for (auto it = s.submitted_on.rbegin(); it != s.submitted_on.rend(); ++it) {
        if (queues_done.count(it->second.queue) || completes(it->second)) {
            s.waited.insert(it->first);
            queues_done.insert(it->second.queue);
        }
    }
}

void forget_pre_range_structure(DeviceState& d, uint64_t acceleration_structure) {
    PreRangeStore& s = store_of(d);
    std::lock_guard lock(s.mutex);
    if (s.written) return;
    supersede(s, acceleration_structure);
    s.nv_memory.erase(acceleration_structure);
}

void forget_pre_range_memory(DeviceState& d, uint64_t memory) {
    PreRangeStore& s = store_of(d);
    std::lock_guard lock(s.mutex);
    if (s.written) return;
    std::set<uint64_t> gone;
    for (const auto& [key, k] : s.kept)
        if (k.memories.count(memory)) gone.insert(k.current.begin(), k.current.end());
    for (uint64_t structure : gone) supersede(s, structure);
    for (auto it = s.nv_memory.begin(); it != s.nv_memory.end();)
        it = it->second == memory ? s.nv_memory.erase(it) : std::next(it);
    for (const auto& [begin, end] : d.memory_map.address_ranges_in(memory))
        s.clusters.freed(begin, end);
}

void note_pre_range_nv_memory(DeviceState& d, uint64_t structure, uint64_t memory) {
    const LayerConfig& config = layer_config();
    if (!config.pre_range_state || config.frame_range.first == 0 || !d.capturing_now()) return;
    PreRangeStore& s = store_of(d);
    std::lock_guard lock(s.mutex);
    if (!s.written) s.nv_memory[structure] = memory;
}

bool pre_range_prelude_due(DeviceState& d) {
    PreRangeStore& s = store_of(d);
    std::lock_guard lock(s.mutex);
    if (s.written || (s.kept.empty() && s.clusters.size() == 0)) {
        s.written = true;  // the range started: nothing more is kept
        s.nv_memory.clear();
        return false;
    }
    return true;
}

// Whether a capture of a submission the application saw complete has not come yet.
bool waited_capture_to_come(const PreRangeStore& s) {
    for (const CaptureKey& key : s.clusters.still_to_come())
        if (s.waited.count(std::get<0>(key))) return true;
    for (const auto& [key, k] : s.kept)
        if (!k.capture && s.waited.count(std::get<0>(key))) return true;
    return false;
}

// The prelude does not wait for the captures of work still running: the application's queue may
// reach their pauses only after this vkQueueSubmit returns (a presenting application's next
// acquire), so they are forwarded to the sink as they come (forward_late_capture), and the sink
// holds the prelude and everything after it until then. Captures of submissions the application
// already waited for come from the layer's own threads alone: for those it waits, a bounded
// time, so which older commands the prelude keeps does not depend on thread scheduling.
void write_pre_range_prelude(DeviceState& d, const SubmissionRecord& captured, uint64_t index) {
    PreRangeStore& s = store_of(d);
    std::unique_lock lock(s.mutex);
    if (s.written) return;
    constexpr auto kPatience = std::chrono::seconds(10);
    if (!s.capture_arrived.wait_for(lock, kPatience, [&] { return !waited_capture_to_come(s); }))
        log_message(LogLevel::kInfo,
                    "pre-range state: captures of submissions the application waited for did "
                    "not come within %lld s; the prelude keeps the older commands they may "
                    "overwrite",
                    (long long)kPatience.count());
    if (s.written) return;
    s.written = true;
    s.nv_memory.clear();
    d.sink->pre_range_state_written(marker_of(s, captured, index));

    RecordedCommandBuffer cb;
    cb.command_buffer = kPreRangeCommandBuffer;
    cb.usage = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    std::vector<ClusterBuildCapture> captures;
    // Each command after a full barrier, with a fresh pause id: unique within the prelude.
    const auto next_pause_id = [&](const CaptureKey& key,
                                   std::optional<ClusterBuildCapture>& capture) -> uint64_t {
        if (!cb.commands.empty()) cb.commands.push_back(full_barrier());
        const uint64_t pause_id = ++d.pause_counter;
        if (!capture) {
            s.forwarded[key] = {index, pause_id};
            return pause_id;
        }
        capture->pause_id = pause_id;
        capture->occurrence = 0;
        capture->submission_index = index;
        capture->command_buffer = kPreRangeCommandBuffer;
        captures.push_back(std::move(*capture));
        return pause_id;
    };
    // Cluster objects first: a KHR top level may name a cluster BLAS.
    for (PreRangeClusterCommands::Taken& t : s.clusters.take()) {
        t.command.pause_id = next_pause_id(t.key, t.capture);
        cb.commands.push_back(std::move(t.command));
    }
    std::map<const KeptCommand*, CaptureKey> key_of;
    for (auto& [key, k] : s.kept) key_of[&k] = key;
    for (KeptCommand* k : prelude_order(s)) {
        pause_id_in(k->command) = next_pause_id(key_of[k], k->capture);
        cb.commands.push_back(std::move(k->command));
    }
    s.kept.clear();
    // The sink learns the prelude's command buffer and submission before any late capture
    // arrives for it: the lock is held until then.
    d.sink->command_buffer_recorded(cb);
    for (ClusterBuildCapture& c : captures) d.sink->cluster_build_captured(std::move(c));
    SubmissionRecord prelude;
    prelude.index = index;
    prelude.queue = captured.queue;
    prelude.queue_family = captured.queue_family;
    prelude.queue_index = captured.queue_index;
    prelude.synchronization2 = true;
    prelude.batches.push_back({{}, {kPreRangeCommandBuffer}, {}});
    d.sink->queue_submitted(prelude);
    lock.unlock();
    HostSyncRecord idle;
    idle.kind = HostSyncRecord::Kind::kDeviceWaitIdle;
    d.sink->host_synchronized(idle);
}

}  // namespace clastrace::capture
