// SPDX-License-Identifier: Apache-2.0
#include "pause_worker.h"

#include "clastrace/capture/cluster_input_walker.h"
#include "layer_state.h"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <pthread.h>

#include "clastrace/capture/acceleration_structure_walker.h"
#include "clastrace/capture/khr_input_walker.h"
#include "clastrace/capture/capture_cost.h"
#include "clastrace/capture/cluster_limits.h"
#include "clastrace/capture/served_build.h"
#include "clastrace/capture/uncached_copy.h"
#include "layer_pre_range.h"

namespace clastrace::capture {

namespace {
// About a microsecond of busy waiting that leaves the core's other hyperthread its share.
void spin_briefly() {
    for (int i = 0; i < 32; ++i) {
#if defined(__x86_64__) || defined(__i386__)
        __builtin_ia32_pause();
#elif defined(__aarch64__)
        asm volatile("yield");
#endif
    }
}

const char* const kNotStaged =
    "the memory is not host visible and the buffer has no acceleration-structure usage (build "
    "input or storage), "
    "so the layer did not stage it";
}  // namespace

PauseWorker::PauseWorker(DeviceState& device) : device_(device), thread_([this] { run(); }) {}

PauseWorker::~PauseWorker() {
    {
        std::lock_guard lock(mutex_);
        stop_ = true;
    }
    wake_.notify_all();
    thread_.join();
    if (pause_milliseconds_.empty()) return;
    std::vector<float> sorted = pause_milliseconds_;
    std::sort(sorted.begin(), sorted.end());
    auto at = [&](double q) {
        return sorted[std::min(sorted.size() - 1, size_t(q * double(sorted.size())))];
    };
    // With CLASTRACE_STATS at any log level: the overhead bench reads it without info logging,
    // which writes a line per served build.
    log_message(
        layer_config().stats ? LogLevel::kQuiet : LogLevel::kInfo,
        "pauses: %zu handled; host time per pause: median %.3f ms, p90 %.3f ms, max %.3f ms",
        sorted.size(), at(0.5), at(0.9), sorted.back());
}

void PauseWorker::expect(VkQueue queue, uint64_t submission_index, bool capture_this_submission,
                         uint64_t command_buffer, const std::vector<PausePoint>& pauses) {
    if (pauses.empty()) return;
    {
        std::lock_guard lock(mutex_);
        auto& pending = queues_[queue];
        for (const PausePoint& p : pauses) {
            pending.push_back(
                {queue, p, submission_index, command_buffer, capture_this_submission});
            if (p.shared) shared_.expected(handle_id(queue), handle_id(p.release));
        }
    }
    wake_.notify_all();
}

bool PauseWorker::wait_until_free(VkQueue queue, const std::vector<uint64_t>& releases,
                                  std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    auto is_reset = [this](uint64_t release) {
        return device_.next.GetEventStatus(device_.device, (VkEvent)release) == VK_EVENT_RESET;
    };
    std::unique_lock lock(mutex_);
    while (shared_.busy_elsewhere(handle_id(queue), releases, is_reset)) {
        if (std::chrono::steady_clock::now() >= deadline) return false;
        lock.unlock();
        std::this_thread::sleep_for(std::chrono::microseconds(100));
        lock.lock();
    }
    return true;
}

void PauseWorker::forget_events(const std::vector<VkEvent>& events) {
    std::lock_guard lock(mutex_);
    if (shared_.empty()) return;
    for (VkEvent e : events) shared_.forget(handle_id(e));
}

void PauseWorker::run() {
    mark_layer_thread();
    pthread_setname_np(pthread_self(), "clastrace-pause");  // for profilers and top
    struct CpuAtExit {  // the worker's CPU time, for CLASTRACE_STATS
        ~CpuAtExit() { add_thread_cpu(CostThread::kPauseWorker, thread_cpu_ns()); }
    } cpu_at_exit;
    using Clock = std::chrono::steady_clock;
    auto last_progress = Clock::now();
    std::unique_lock lock(mutex_);
    while (!stop_) {
        bool any_pending = false;
        bool progressed = false;
        for (auto& [queue, pending] : queues_) {
            if (pending.empty()) continue;
            any_pending = true;
            Expected head = pending.front();
            lock.unlock();
            const bool done = handle(head);
            lock.lock();
            if (done) {
                auto& list = queues_[queue];
                if (!list.empty()) list.pop_front();
                progressed = true;
            }
        }
        if (!any_pending) {
            lock.unlock();
            // idle: free the written records' bytes here, where they were allocated
            if (device_.sink) device_.sink->release_written();
            make_regions_ready();
            lock.lock();
            wake_.wait(lock, [this] {
                return stop_ || std::any_of(queues_.begin(), queues_.end(),
                                            [](auto& q) { return !q.second.empty(); });
            });
            last_progress = Clock::now();
            continue;
        }
        if (progressed) {
            last_progress = Clock::now();
            continue;
        }
        // A queue is about to reach a pause or is still far from it: spin briefly (the queue is
        // stalled while we sleep), then back off so an idle wait does not burn a core. The spin
        // does not yield: a yield can hand the core to the sink's and compressor's background
        // threads until the next scheduler tick, while the queue may already wait.
        lock.unlock();
        if (Clock::now() - last_progress < std::chrono::microseconds(2000))
            spin_briefly();
        else
            std::this_thread::sleep_for(std::chrono::microseconds(50));
        lock.lock();
    }
}

// Called idle, without mutex_: stops as soon as a pause is expected (the pool's regions are
// made one at a time, each a few milliseconds at most).
void PauseWorker::make_regions_ready() {
    while (region_pool_->make_one_ready()) {
        std::lock_guard lock(mutex_);
        if (stop_ ||
            std::any_of(queues_.begin(), queues_.end(), [](auto& q) { return !q.second.empty(); }))
            return;
    }
}

const uint8_t* PauseWorker::staged_bytes(const ResolvedRange& range) {
    if (range.host) return range.host;
    const StagedBuffer* staged = staging_ ? staging_->find(range.buffer.handle) : nullptr;
    if (!staged) return nullptr;
    if (!staging_->coherent) {  // the queue's copy reaches the host view only after an invalidate
        VkMappedMemoryRange whole{VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE, nullptr, staging_->memory,
                                  0, VK_WHOLE_SIZE};
        device_.next.InvalidateMappedMemoryRanges(device_.device, 1, &whole);
    }
    return staging_->host + staged->offset + range.offset_in_buffer;
}

bool PauseWorker::check_memory(VkDeviceAddress address, uint64_t size, std::string& why) {
    auto range = device_.memory_map.resolve(address, size, why);
    if (!range) return false;
    if (!range->host && !(staging_ && staging_->find(range->buffer.handle))) {
        why = kNotStaged;
        return false;
    }
    return true;
}

bool PauseWorker::read_resolved(const ResolvedRange& range, uint64_t size, CapturedBytes& out) {
    if (!range.host) {
        const uint8_t* staged = staged_bytes(range);
        if (!staged) return false;
        uint8_t* to = out.fill(size);
        if (staging_->cached)
            std::memcpy(to, staged, size);
        else
            copy_from_uncached(to, staged, size);
        return true;
    }
    if (!(range.memory.property_flags & VK_MEMORY_PROPERTY_HOST_COHERENT_BIT)) {
        // Device writes to non-coherent memory reach the host view only after an invalidate of
        // whole atoms.
        const VkDeviceSize atom = device_.non_coherent_atom_size;
        const VkDeviceSize first = range.buffer.memory_offset + range.offset_in_buffer;
        const VkDeviceSize begin = first / atom * atom;
        const VkDeviceSize end = (first + size + atom - 1) / atom * atom;
        VkMappedMemoryRange mapped{VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE, nullptr,
                                   (VkDeviceMemory)range.memory.handle, begin,
                                   end >= range.memory.size ? VK_WHOLE_SIZE : end - begin};
        device_.next.InvalidateMappedMemoryRanges(device_.device, 1, &mapped);
    }
    uint8_t* to = out.fill(size);
    if (range.memory.property_flags & VK_MEMORY_PROPERTY_HOST_CACHED_BIT) {
        if (size) std::memcpy(to, range.host, size);
    } else {
        copy_from_uncached(to, range.host, size);
    }
    return true;
}

bool PauseWorker::read_memory(VkDeviceAddress address, uint64_t size, CapturedBytes& out,
                              std::string& why) {
    auto range = device_.memory_map.resolve(address, size, why);
    if (!range) return false;
    if (!read_resolved(*range, size, out)) {
        why = kNotStaged;
        return false;
    }
    return true;
}

bool PauseWorker::handle(Expected& expected) {
    const PausePoint& pause = expected.pause;
    if (pause.address_writes) return handle_address_writes(expected);
    if (device_.next.GetEventStatus(device_.device, pause.signal) != VK_EVENT_SET) return false;
    const auto started = std::chrono::steady_clock::now();
    const uint64_t started_cpu = thread_cpu_ns();
    staging_ = pause.staging.get();
    const bool capture = expected.capture && device_.capturing_now();
    // A served build reads the application's memory through the engine's image; the capture's
    // walk reads through the same copy, so each byte crosses from (often uncached) memory once,
    // and its ranges are views into that copy rather than copies of their own.
    std::unique_ptr<ServedMemory> served;
    if (device_.serving && pause.phase == PausePhase::kBeforeCommand && pause.parameters) {
        served = std::make_unique<ServedMemory>(prepare_served_buffers(), region_pool_);
        overlay_traceable_bytes(device_, *served);
    }
    DeviceMemoryReader reader = [this, &served](VkDeviceAddress a, uint64_t s, CapturedBytes* o,
                                                std::string& w) {
        if (served && served->view(a, s, o))
            return true;  // (executeServedBuild keeps them what was read)
        if (!o) return check_memory(a, s, w);
        return read_memory(a, s, *o, w);
    };

    ClusterBuildCapture* record = nullptr;
    const OpenKey open_key =
        std::make_tuple(expected.submission_index, pause.pause_id, pause.occurrence);
    if (capture) {
        CostScope cost(CostPhase::kPauseRead, false, CostPhase::kPauseCopyIn);
        if (pause.phase == PausePhase::kBeforeCommand) {
            record = open_record(expected, open_key, reader);
            if (layer_config().host_writes)
                device_.host_writes.paused(expected.submission_index, pause.pause_id,
                                           record->inputs);
        } else
            record = add_outputs_to_open_record(pause, open_key, reader);
    }
    std::shared_ptr<const engine::MemoryImage> served_image;
    if (served) served_image = finish_served_command(pause, *served, record, reader);
    const double stalled = release_queue(expected, started, started_cpu);
    if (served) region_pool_->pause_ended();
    staging_ = nullptr;  // the queue may overwrite the staged copies from here on
    if (!record) return true;
    record->pause_milliseconds += stalled;
    if (!pause.last_of_command) {  // the record waits in open_ for the command's next pause
        name_ranges(*record);
        return true;
    }
    pass_record_on(open_key, pause.parameters, std::move(served_image), std::move(served));
    return true;
}

bool PauseWorker::handle_address_writes(Expected& expected) {
    const PausePoint& pause = expected.pause;
    if (device_.next.GetEventStatus(device_.device, pause.signal) != VK_EVENT_SET) return false;
    const auto started = std::chrono::steady_clock::now();
    const uint64_t started_cpu = thread_cpu_ns();
    staging_ = pause.staging.get();
    const bool capture = expected.capture && device_.capturing_now();
    const OpenKey key =
        std::make_tuple(expected.submission_index, pause.pause_id, pause.occurrence);
    AddressWriteComparison compared;
    if (capture) {
        CostScope cost(CostPhase::kPauseRead);
        const std::vector<ServedBuffer> buffers = prepare_served_buffers();
        if (pause.phase == PausePhase::kBeforeCommand)
            address_writes_.before(key, buffers);
        else
            compared = address_writes_.after(key, buffers);
    }
    const double stalled = release_queue(expected, started, started_cpu);
    staging_ = nullptr;  // the queue may overwrite the staged copies from here on
    // Every execution the sink expects gets its record, empty where nothing was compared.
    if (!capture || pause.phase != PausePhase::kAfterCommand) return true;
    ClusterBuildCapture record;
    record.kind = CapturedCommandKind::kDeviceAddressWrites;
    record.pause_id = pause.pause_id;
    record.occurrence = pause.occurrence;
    record.submission_index = expected.submission_index;
    record.command_buffer = expected.command_buffer;
    record.outputs = std::move(compared.changed);
    record.compared_bytes = compared.compared_bytes;
    record.pause_milliseconds = stalled;
    device_.sink->cluster_build_captured(std::move(record));
    return true;
}

// Opens the capture of a command at its pause before it, with the inputs the command reads.
ClusterBuildCapture* PauseWorker::open_record(const Expected& expected, const OpenKey& key,
                                              const DeviceMemoryReader& reader) {
    const PausePoint& pause = expected.pause;
    ClusterBuildCapture fresh;
    fresh.pause_id = pause.pause_id;
    fresh.occurrence = pause.occurrence;
    fresh.submission_index = expected.submission_index;
    fresh.command_buffer = expected.command_buffer;
    ClusterMemoryWalk walk = walk_command_inputs(pause, fresh, reader);
    ClusterBuildCapture* record = &open_.insert_or_assign(key, std::move(fresh)).first->second;
    record->executed_count = walk.executed_count;
    record->inputs = std::move(walk.ranges);
    record->issues = std::move(walk.issues);
    return record;
}

// Walks the inputs of the pause's command, by its kind; sets `record`'s kind and parameters.
ClusterMemoryWalk PauseWorker::walk_command_inputs(const PausePoint& pause,
                                                   ClusterBuildCapture& record,
                                                   const DeviceMemoryReader& reader) {
    BufferMemoryReader buffer_reader = [this](uint64_t buffer, VkDeviceSize offset, uint64_t size,
                                              CapturedBytes* out, std::string& why) {
        auto range = device_.memory_map.resolve_buffer(buffer, offset, size, why);
        if (!range) return false;
        if (!range->host && !(staging_ && staging_->find(range->buffer.handle))) {
            why = kNotStaged;
            return false;
        }
        return out ? read_resolved(*range, size, *out) : true;
    };
    if (pause.build_khr) {
        record.kind = CapturedCommandKind::kBuildAccelerationStructuresKhr;
        ClusterMemoryWalk walk =
            walk_build_acceleration_structures_khr_inputs(*pause.build_khr, reader, buffer_reader,
                                                          record.khr_indirect_ranges);
        device_.nv_scene.observe_khr_build(*pause.build_khr, record.khr_indirect_ranges,
                                           walk.ranges);  // for the ray check
        return walk;
    }
    if (pause.copy_acceleration_structure) {
        record.kind = CapturedCommandKind::kCopyAccelerationStructure;
        return walk_copy_acceleration_structure_inputs(*pause.copy_acceleration_structure,
                                                       buffer_reader);
    }
    if (pause.build_nv) {
        record.kind = CapturedCommandKind::kBuildAccelerationStructureNv;
        ClusterMemoryWalk walk =
            walk_build_acceleration_structure_nv_inputs(*pause.build_nv, buffer_reader);
        device_.nv_scene.observe_build(*pause.build_nv, walk.ranges);  // for the ray check
        return walk;
    }
    if (pause.trace_rays) {
        record.kind = CapturedCommandKind::kTraceRays;
        ClusterMemoryWalk walk;
        const TraceRaysCommand& c = *pause.trace_rays;
        CapturedRange range{MemoryRole::kTraceRaysIndirect, 0, c.indirect_address, {}};
        std::string why;
        if (reader(c.indirect_address, c.indirect_size, &range.bytes, why))
            walk.ranges.push_back(std::move(range));
        else
            walk.issues.push_back(
                {c.indirect_address, c.indirect_size, "indirect ray dimensions: " + why});
        return walk;
    }
    if (pause.copy_to_acceleration_structure) {
        record.kind = CapturedCommandKind::kCopyMemoryToAccelerationStructure;
        return walk_copy_memory_to_acceleration_structure_inputs(
            *pause.copy_to_acceleration_structure, reader);
    }
    record.parameters = *pause.parameters;
    ClusterMemoryWalk walk =
        walk_cluster_inputs(*pause.parameters, reader,
                            [this](VkDeviceAddress address, uint32_t* vertices) {
                                auto it = template_vertex_counts_.find(address);
                                if (it == template_vertex_counts_.end()) return false;
                                *vertices = it->second;
                                return true;
                            });
    if (!walk.template_vertex_counts.empty())
        pending_template_vertex_counts_[pause.pause_id] = std::move(walk.template_vertex_counts);
    else if (pause.parameters->info.input.opType ==
                 VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV &&
             pause.parameters->move_objects_input.type ==
                 VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_TEMPLATE_NV)
        pending_template_vertex_counts_[pause.pause_id] =
            moved_template_vertex_counts(*pause.parameters, walk.executed_count);
    return walk;
}

// At the pause after a cluster command: its outputs join the record its first pause opened
// (null when there is none).
ClusterBuildCapture* PauseWorker::add_outputs_to_open_record(const PausePoint& pause,
                                                             const OpenKey& key,
                                                             const DeviceMemoryReader& reader) {
    auto it = open_.find(key);
    if (it == open_.end() || !pause.parameters) return nullptr;
    ClusterBuildCapture* record = &it->second;
    add_outputs(*record, *pause.parameters, reader);
    learn_pending_templates(pause);
    return record;
}

void PauseWorker::add_outputs(ClusterBuildCapture& record,
                              const ClusterCommandParameters& parameters,
                              const DeviceMemoryReader& reader) {
    ClusterMemoryWalk walk = walk_cluster_outputs(parameters, record.executed_count, reader);
    record.outputs = std::move(walk.ranges);
    for (auto& issue : walk.issues) record.issues.push_back(std::move(issue));
}

// The templates the pause's command built (or moved), once its dstAddressesArray is written.
void PauseWorker::learn_pending_templates(const PausePoint& pause) {
    auto pending = pending_template_vertex_counts_.find(pause.pause_id);
    if (pending == pending_template_vertex_counts_.end()) return;
    learn_templates(*pause.parameters, pending->second);
    pending_template_vertex_counts_.erase(pending);
}

// Served, the command has executed once the engine returns, and its outputs are what a pause
// after it would read (the queue runs nothing in between). The engine's image holds them (and
// everything the command read), so they are walked there after the queue is released; if
// the engine could not run, from memory now.
std::shared_ptr<const engine::MemoryImage> PauseWorker::finish_served_command(
    const PausePoint& pause, ServedMemory& served, ClusterBuildCapture* record,
    const DeviceMemoryReader& reader) {
    std::shared_ptr<const engine::MemoryImage> served_image;
    {
        CostScope cost(CostPhase::kPauseEngine, false, CostPhase::kPauseCopyIn);
        served_image = execute_served(pause, served, record);
    }
    // No pause follows a served command: learn the templates it built (or moved) now, while
    // its dstAddressesArray holds what the engine just wrote and the queue still waits.
    if (pause.last_of_command) learn_pending_templates(pause);
    if (record && pause.last_of_command && !served_image)
        add_outputs(*record, *pause.parameters, reader);
    return served_image;
}

// Lets the queue run on past the pause; returns how long it was held, in milliseconds.
double PauseWorker::release_queue(const Expected& expected,
                                  std::chrono::steady_clock::time_point started,
                                  uint64_t started_cpu) {
    const PausePoint& pause = expected.pause;
    device_.next.ResetEvent(device_.device, pause.signal);
    device_.next.SetEvent(device_.device, pause.release);
    if (pause.shared) {
        std::lock_guard lock(mutex_);
        shared_.released(handle_id(expected.queue), handle_id(pause.release));
    }
    ++handled_;
    const auto released = std::chrono::steady_clock::now();
    const uint64_t released_cpu = thread_cpu_ns();
    const double stalled = std::chrono::duration<double, std::milli>(released - started).count();
    pause_milliseconds_.push_back(float(stalled));
    add_cost(CostPhase::kPauseHeld, uint64_t(stalled * 1e6), released_cpu - started_cpu);
    return stalled;
}

// Hands the finished record of the command to the sink.
// A served record leaves unfinished: the sink's thread walks its outputs in the engine's
// image and names its ranges by this pause's buffers (the application may destroy them once
// the queue moved on), while this thread takes the next pause. Any other record is named now,
// by the memory map, before the queue passes its last pause and the application may destroy
// the buffers that name the ranges.
void PauseWorker::pass_record_on(const OpenKey& key,
                                 std::shared_ptr<const ClusterCommandParameters> parameters,
                                 std::shared_ptr<const engine::MemoryImage> served_image,
                                 std::unique_ptr<ServedMemory> served) {
    auto it = open_.find(key);
    ClusterBuildCapture work = std::move(it->second);
    open_.erase(it);
    if (served_image) {  // (set only when the build was served and ran)
        work.held_bytes = served_image->resident_bytes();
        work.complete = [image = std::move(served_image), parameters = std::move(parameters),
                         memory = std::shared_ptr<const ServedMemory>(std::move(served))](
                            ClusterBuildCapture& r) {
            complete_served_record(r, image, *parameters, *memory);
        };
    } else {
        name_ranges(work);
    }
    if (take_pre_range_capture(device_, work)) return;  // kept for the frame range's prelude
    device_.sink->cluster_build_captured(std::move(work));
}

// By a buffer holding each, as the trace's snapshots do: the memory map now.
void PauseWorker::name_ranges(ClusterBuildCapture& record) {
    for (auto* list : {&record.inputs, &record.outputs})
        for (CapturedRange& r : *list) {
            std::string why;
            if (r.address == 0) continue;  // named by buffer and offset already
            if (auto where = device_.memory_map.resolve(r.address, r.bytes.size(), why)) {
                r.buffer = where->buffer.handle;
                r.buffer_offset = where->offset_in_buffer;
            }
        }
}

void PauseWorker::learn_templates(const ClusterCommandParameters& parameters,
                                  const std::vector<uint32_t>& vertex_counts) {
    const auto& info = parameters.info;
    if (info.input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV ||
        (info.addressResolutionFlags &
         VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV))
        return;
    const uint64_t stride = info.dstAddressesArray.stride ? info.dstAddressesArray.stride : 8;
    for (size_t i = 0; i < vertex_counts.size(); ++i) {
        CapturedBytes bytes;
        std::string why;
        if (!read_memory(info.dstAddressesArray.deviceAddress + i * stride, 8, bytes, why)) return;
        uint64_t address;
        std::memcpy(&address, bytes.data(), 8);
        if (address != 0 && vertex_counts[i] != 0)
            template_vertex_counts_[address] = vertex_counts[i];
    }
}

std::vector<uint32_t> PauseWorker::moved_template_vertex_counts(
    const ClusterCommandParameters& parameters, uint32_t executed_count) {
    std::vector<uint32_t> counts;
    const auto& info = parameters.info;
    if (info.addressResolutionFlags &
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV)
        return counts;
    const uint64_t stride = info.srcInfosArray.stride ? info.srcInfosArray.stride : 8;
    for (uint32_t i = 0; i < executed_count; ++i) {
        CapturedBytes bytes;
        std::string why;
        if (!read_memory(info.srcInfosArray.deviceAddress + i * stride, 8, bytes, why)) break;
        uint64_t
            source;  // VkClusterAccelerationStructureMoveObjectsInfoNV::srcAccelerationStructure
        std::memcpy(&source, bytes.data(), 8);
        auto it = template_vertex_counts_.find(source);
        counts.push_back(
            it == template_vertex_counts_.end() ? 0 : it->second);  // 0: unknown, not learned
    }
    return counts;
}

std::vector<ServedBuffer> PauseWorker::prepare_served_buffers() {
    std::vector<ResolvedRange> held = device_.memory_map.host_addressed_buffers();
    std::vector<ServedBuffer> buffers;
    buffers.reserve(held.size());
    for (const ResolvedRange& r : held)
        buffers.push_back({r.buffer.handle, r.buffer.address, r.buffer.size, r.buffer.usage, r.host,
                           r.memory.handle,
                           (r.memory.property_flags & VK_MEMORY_PROPERTY_HOST_CACHED_BIT) != 0,
                           (r.memory.property_flags & VK_MEMORY_PROPERTY_HOST_COHERENT_BIT) != 0});
    // Unmapped buffers take part through their staged copies; the queue copies them back.
    if (staging_)
        for (const StagedBuffer& b : staging_->buffers)
            buffers.push_back({b.buffer.handle, b.buffer.address, b.buffer.size, b.buffer.usage,
                               staging_->host + b.offset, handle_id(staging_->memory),
                               staging_->cached, staging_->coherent});
    // What the device wrote to non-coherent memory reaches the host view only after an invalidate.
    std::vector<uint64_t> invalidated;
    for (const ServedBuffer& b : buffers) {
        if (b.coherent ||
            std::find(invalidated.begin(), invalidated.end(), b.memory) != invalidated.end())
            continue;
        invalidated.push_back(b.memory);
        VkMappedMemoryRange range{VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE, nullptr,
                                  (VkDeviceMemory)b.memory, 0, VK_WHOLE_SIZE};
        device_.next.InvalidateMappedMemoryRanges(device_.device, 1, &range);
    }
    return buffers;
}

std::shared_ptr<const engine::MemoryImage> PauseWorker::execute_served(
    const PausePoint& pause, ServedMemory& memory, ClusterBuildCapture* record) {
    // Traceable BLASes at implicit destinations: each object gets room for the driver's BVH.
    const uint64_t room = traceable_implicit_room(device_, pause.parameters->resolved(), memory);
    if (record) record->implicit_object_room = room;
    ServedExecution served = execute_served_build(
        pause.parameters->resolved(), memory, directory_, served_engine_properties(),
        record ? &record->inputs : nullptr,
        record ? std::optional<uint32_t>(record->executed_count) : std::nullopt,
        [&](const engine::MemoryImage& image, const engine::ExecutionRecord& run) {
            build_traceable_blases(device_, pause.pause_id, pause.parameters->resolved(), image,
                                   memory, run.ops, record ? &record->driver_bvh : nullptr);
        },
        room);
    if (!served.ran) {
        log_message(LogLevel::kError, "served build (pause %llu) could not run in the engine: %s",
                    (unsigned long long)pause.pause_id, served.error.c_str());
        if (record)
            record->engine_findings.push_back(
                {"CLASTRACE-engine-could-not-run", served.error, -1, 0});
        return nullptr;
    }
    const std::span<const ServedBuffer> buffers = memory.buffers();
    for (uint64_t written : served.written_memories)
        if (std::any_of(buffers.begin(), buffers.end(), [&](const ServedBuffer& b) {
                return b.memory == written && !b.coherent;
            })) {
            VkMappedMemoryRange range{VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE, nullptr,
                                      (VkDeviceMemory)written, 0, VK_WHOLE_SIZE};
            device_.next.FlushMappedMemoryRanges(device_.device, 1, &range);
        }
    log_message(LogLevel::kInfo,
                "served build (pause %llu): %u ops executed by the engine, %zu findings, %llu "
                "bytes read in "
                "(%u runs), %llu bytes written",
                (unsigned long long)pause.pause_id, served.record.op_count,
                served.record.findings.size(), (unsigned long long)served.bytes_copied_in,
                served.attempts, (unsigned long long)served.bytes_written_back);
    // An application repeating one mistake every frame would bury everything else: each rule is
    // logged a few times per device, then once more to say the rest are counted, not printed.
    constexpr uint64_t kLoggedPerRule = 8;
    for (const engine::Finding& f : served.record.findings) {
        const uint64_t seen = ++findings_per_rule_[f.rule];
        if (seen <= kLoggedPerRule)
            log_message(LogLevel::kError, "served build (pause %llu) op %lld: %s: %s",
                        (unsigned long long)pause.pause_id, (long long)f.op_index, f.rule.c_str(),
                        f.message.c_str());
        if (seen == kLoggedPerRule)
            log_message(
                LogLevel::kError,
                "%s: further findings of this rule on this device are not logged (a capture keeps "
                "them all)",
                f.rule.c_str());
    }
    if (record) {
        record->executed_by_engine = true;
        for (const engine::Finding& f : served.record.findings)
            record->engine_findings.push_back({f.rule, f.message, f.op_index, f.address});
    }
    return served.image;
}

}  // namespace clastrace::capture
