// SPDX-License-Identifier: Apache-2.0
// The .clt trace sink. The trace is a linear story the replay walks in order, while the layer
// learns a command's memory only when the queue executes it, after vkQueueSubmit returned.
// So state records (memory, buffers, size queries) are appended at once, and a submission's
// command buffers are written out, each as Begin..End with the snapshots of its cluster
// builds, followed by its QueueSubmit, once every build of that submission was captured.
//
// Two locks, so the application's threads and the pause worker never wait while a submission
// is hashed, framed and handed to the compressor: `mutex_` guards what the calls change (held
// for map updates only), and everything bound for the file goes, in trace order, through
// `outbox_`; whoever holds `writeMutex_` (the sink's thread, or a flush) takes the outbox and
// writes it. Lock order: writeMutex_ before mutex_. Only the sink's thread and the
// application's first vkCreateDevice and last flush take writeMutex_: the pause worker and the
// application's calls never wait for the writing (a host write's bytes are stored by the
// writing side too). The sink's thread runs in SCHED_IDLE (idle_priority.h); whoever finds
// mutex_ taken, or the captured bytes past kMaxPendingBytes, raises it to the normal class so
// that it cannot be starved while others wait for it.
#include "clastrace/capture/capture_sink.h"
#include "clastrace/capture/background_cpus.h"

#include "clastrace/capture/capture_cost.h"
#include "clastrace/capture/layer_config.h"
#include "idle_priority.h"
#include "trace_record_encoding.h"

#include <clastrace/traces/cluster_conversions.h>
#include <clastrace/traces/sparse_conversions.h>

#include <clastrace/traces/output_file.h>
#include <clastrace/traces/trace_writer.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <condition_variable>
#include <thread>
#include <tuple>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <deque>
#include <map>
#include <mutex>
#include <optional>
#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <unistd.h>
#include <unordered_map>
#include <utility>
#include <variant>

namespace clastrace::capture {
namespace {

namespace fbs = clastrace::fbs;
using traces::TraceError;
using traces::TraceWriter;

class TraceCaptureSink final : public CaptureSink {
public:
    TraceCaptureSink(std::string path, int output_fd, int zstd_level, uint32_t flush_milliseconds,
                     BackgroundPlacement placement)
        : path_(std::move(path)),
          output_fd_(output_fd),
          zstd_level_(zstd_level),
          flush_milliseconds_(flush_milliseconds),
          placement_(std::move(placement)) {
        emitter_ = std::thread([this] { emit_in_background(); });
        priority_.attach(emitter_.native_handle());
        // Placed from here, not from the thread: the stats line must not depend on whether the
        // idle-priority thread has run yet.
        if (!placement_.cpus.empty()) (void)place_thread(emitter_.native_handle(), placement_.cpus);
        std::lock_guard lock(placement_mutex_);
        sink_cpus_ = thread_cpus(emitter_.native_handle());  // what the kernel gave
    }
    ~TraceCaptureSink() override {
        {
            std::lock_guard lock(wake_mutex_);
            stop_emitting_ = true;
        }
        priority_.raise();  // what it writes now, the application waits for
        wake_.notify_all();
        emitter_.join();
        std::lock_guard write(write_mutex_);
        {
            StateLock lock(*this);
            emit_ready_locked(true);
        }
        write_outbox_locked();
        if (writer_ && !failed_) check(writer_->finish());
        if (output_fd_ >= 0) ::close(output_fd_);  // no device came: the output was left untouched
    }
    bool active() const override { return !failed_; }

    void device_created(const DeviceRecord& d) override {
        auto write = lock_writer();
        StateLock lock(*this);
        if (writer_ || failed_) return;  // the header describes the first device
        const fbs::TraceHeaderT header =
            trace_header_of(d, uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                            std::chrono::system_clock::now().time_since_epoch())
                                            .count()));
        traces::TraceWriterOptions options;
        options.zstd_level = zstd_level_;
        // Nice 10, not SCHED_IDLE: the sink's thread, raised while others wait for it, waits for
        // the compressor in turn (a full queue), and nobody can raise the compressor's thread.
        options.compressor_nice = kBackgroundNice;
        options.compressor_idle_class = false;
        options.compressor_cpus = placement_.cpus;
        options.delta_contents = layer_config().delta_contents;
        TraceError error;
        writer_ =
            TraceWriter::create_on(std::exchange(output_fd_, -1), path_, header, options, &error);
        if (!writer_) fail(error);
    }
    void device_destroyed(uint64_t) override {}

    void memory_allocated(const MemoryRecord& m) override {
        fbs::MemoryAllocateT r;
        r.memory = m.memory;
        r.size = m.size;
        r.memory_type_index = m.type_index;
        r.allocate_flags = m.allocate_flags;
        append(record_of(std::move(r)));
    }
    void memory_freed(uint64_t memory) override {
        fbs::MemoryFreeT r;
        r.memory = memory;
        append(record_of(std::move(r)));
    }
    void buffer_created(const BufferRecord& b) override {
        fbs::BufferCreateT r;
        r.buffer = b.buffer;
        r.size = b.size;
        r.usage = b.usage;
        r.create_flags = b.flags;
        r.sharing_mode = uint32_t(b.sharing_mode);
        r.queue_family_indices = b.queue_families;
        append(record_of(std::move(r)));
    }
    // The binding is held back until the application asks for the address (it normally does
    // right after binding), so one BufferBindMemory carries both.
    void buffer_bound(const BufferBindingRecord& b) override {
        StateLock lock(*this);
        pending_binds_[b.buffer] = b;
    }
    void buffer_address_queried(const BufferAddressRecord& a) override {
        StateLock lock(*this);
        auto it = pending_binds_.find(a.buffer);
        if (it == pending_binds_.end()) {
            if (addressed_.count(a.buffer)) return;  // asked again: nothing new
            // Bound before capture saw it, or asked twice after an emitted bind: restate the binding.
            auto known = bound_at_.find(a.buffer);
            if (known == bound_at_.end()) return;
            emit_bind_locked(known->second, a.address, true);
            return;
        }
        emit_bind_locked(it->second, a.address, true);
        pending_binds_.erase(it);
    }
    void buffer_destroyed(uint64_t buffer) override {
        StateLock lock(*this);
        flush_binds_locked(true);
        addressed_.erase(buffer);
        bound_at_.erase(buffer);
        fbs::BufferDestroyT r;
        r.buffer = buffer;
        append_ordered_locked(record_of(std::move(r)));
    }
    void build_sizes_queried(const BuildSizesQuery& q) override {
        fbs::GetClusterBuildSizesT r;
        r.input = traces::cluster_input_to_record(q.input.resolved().input);
        r.acceleration_structure_size = q.answer.accelerationStructureSize;
        r.update_scratch_size = q.answer.updateScratchSize;
        r.build_scratch_size = q.answer.buildScratchSize;
        append(record_of(std::move(r)));
    }
    // After the submissions announced before the call (the results read their queries).
    void query_pool_results_read(const QueryPoolResultsRecord& q) override {
        append(record_of(query_pool_results_of(q)));
    }
    void khr_build_sizes_queried(const KhrBuildSizesQuery& q) override {
        append(record_of(khr_build_sizes_of(q)));
    }
    void command_buffer_recorded(const RecordedCommandBuffer& cb) override {
        auto copy = std::make_shared<RecordedCommandBuffer>(cb);  // outside the lock
        StateLock lock(*this);
        recorded_[cb.command_buffer] = std::move(copy);
    }
    void command_buffer_reset(uint64_t) override {}  // each submission restates its command buffers

    void queue_submitted(const SubmissionRecord& s) override {
        StateLock lock(*this);
        Pending& p = pending_[s.index];
        p.submission = s;
        p.submitted = true;
        if (pre_range_ && pre_range_->prelude_submission == s.index)
            p.pre_range = std::exchange(pre_range_, std::nullopt);
        for (const auto& batch : s.batches)
            for (uint64_t cb : batch.command_buffers) {
                auto it = recorded_.find(cb);
                if (it == recorded_.end()) continue;
                p.command_buffers.push_back(it->second);
                p.expected_builds += captured_commands_of(*it->second);
                if (timestamp_read_of(*it->second))
                    ++p.expected_builds;  // its timestamps' readback
                // Its secondaries as they are now: the application may re-record them once this
                // submission completed, before the sink writes it.
                for (const auto& c : it->second->commands)
                    if (const auto* execute = std::get_if<ExecuteCommandsCommand>(&c))
                        for (uint64_t secondary : execute->secondaries)
                            if (auto found = recorded_.find(secondary); found != recorded_.end()) {
                                p.secondaries.emplace(secondary, found->second);
                                p.expected_builds += captured_commands_of(*found->second);
                            }
            }
        wake_emitter();
    }
    // What a captured build holds until it is written: its ranges' own bytes and the served
    // engine image that its unfinished completion or its output views keep.
    static uint64_t held_bytes_of(const ClusterBuildCapture& c) {
        uint64_t bytes = c.held_bytes;
        for (const auto* list : {&c.inputs, &c.outputs})
            for (const CapturedRange& r : *list) bytes += r.bytes.owned_size();
        return bytes;
    }
    // Commands of `cb` whose execution the worker captures at a pause.
    static size_t captured_commands_of(const RecordedCommandBuffer& cb) {
        size_t n = 0;
        for (const auto& c : cb.commands) n += pause_id_of(c) != 0;
        return n;
    }
    // Hashing and framing the snapshots happen on the sink's thread, never on the pause worker
    // that delivered them. Past kMaxPendingBytes the sink's thread works at the application's
    // priority until it has caught up; past kHardPendingBytes (a writer slower than the capture
    // even so: a slow disk, a pipe) the deliverer waits for it to write what is ready, so memory
    // stays bounded. The pause worker delivers after releasing the queue, so that wait falls
    // between pauses, never inside one.
    void cluster_build_captured(ClusterBuildCapture c) override {
        uint64_t pending = 0;
        {
            StateLock lock(*this);
            pending_bytes_ += held_bytes_of(c);
            pending_[c.submission_index].builds[{c.pause_id, c.occurrence}] = std::move(c);
            pending = pending_bytes_;
        }
        if (pending > kMaxPendingBytes) priority_.raise();
        wake_emitter();
        if (pending > kHardPendingBytes) wait_until_written();
    }
    // Host synchronization goes out after the newest submission already announced, as the
    // application made the call after that vkQueueSubmit returned; a submission still waiting
    // for its builds holds it back with it, so the order in the trace is the order of the calls.
    void host_synchronized(const HostSyncRecord& h) override {
        fbs::RecordT record = host_sync_record_of(h);
        StateLock lock(*this);
        append_ordered_locked(std::move(record));
    }
    // Ordered like host synchronization (the layer reports it from the host call that saw it).
    // Its bytes go to the content store on the writing side, right ahead of the record that
    // names them: the caller holds the host-write watch's lock, which a pause takes, so it must
    // not wait here for the writer.
    void host_write_observed(const HostWriteRecord& w) override {
        Ordered copy = w;  // outside the lock
        StateLock lock(*this);
        append_ordered_locked(std::move(copy));
    }
    // A queue operation like a submission: after the submissions made before the call (a
    // submission waiting on its semaphore is made after it).
    void sparse_bound(const SparseBindRecord& b) override {
        fbs::RecordT record =
            record_of(traces::queue_bind_sparse_to_record(b.queue, std::span(b.infos, b.info_count),
                                                          b.fence, b.result, b.address_of));
        StateLock lock(*this);
        append_ordered_locked(std::move(record));
    }
    // Ordered like host synchronization: after the submissions of the frame it ends.
    void queue_presented(const PresentRecord& p) override {
        fbs::QueuePresentT r;
        r.queue = p.queue;
        r.frame = p.frame;
        r.wait_semaphores = p.wait_semaphores;
        r.swapchains = p.swapchains;
        r.image_indices = p.image_indices;
        r.result = p.result;
        append(record_of(std::move(r)));
    }
    // Ordered like presents: after the submission (or present) that carried it.
    void frame_boundary_marked(const FrameBoundaryRecord& b) override {
        fbs::FrameBoundaryT r;
        r.queue = b.queue;
        r.carrier = uint32_t(b.carrier);
        r.submission = b.submission;
        r.batch = b.batch;
        r.flags = b.flags;
        r.frame_id = b.frame_id;
        r.frame = b.frame;
        r.images = b.images;
        r.buffers = b.buffers;
        r.tag_name = b.tag_name;
        r.tag = b.tag;
        append(record_of(std::move(r)));
    }
    // Announced before the prelude's submission (layer_pre_range.cpp); written just ahead of its
    // QueueSubmit, whose trace index it then names.
    void pre_range_state_written(const PreRangeStateRecord& m) override {
        StateLock lock(*this);
        pre_range_ = m;
    }
    // Ordered like presents: the submission that waits on the semaphore comes after it.
    void image_acquired(const AcquireRecord& a) override {
        fbs::AcquireNextImageT r;
        r.swapchain = a.swapchain;
        r.timeout = a.timeout;
        r.semaphore = a.semaphore;
        r.fence = a.fence;
        r.image_index = a.image_index;
        r.result = a.result;
        r.device_mask = a.device_mask;
        append(record_of(std::move(r)));
    }
    void release_written() override {
        std::vector<decltype(Pending::builds)> written;
        uint64_t bytes = 0;
        {
            std::lock_guard lock(written_mutex_);
            if (written_.empty()) return;
            written.swap(written_);
            bytes = written_bytes_;
            written_bytes_ = 0;
        }
        written.clear();
        StateLock lock(*this);
        pending_bytes_ -= std::min(pending_bytes_.load(), bytes);
    }
    void flush() override {
        CostScope cost(CostPhase::kDeviceFlush, true);
        priority_.raise();  // the application waits for what it writes now
        auto write = lock_writer();
        {
            StateLock lock(*this);
            emit_ready_locked(false);
            flush_binds_locked(false);
        }
        write_outbox_locked();
        if (writer_ && !failed_) check(writer_->flush());
    }
    std::vector<std::string> cost_lines() override {
        std::vector<std::string> lines;
        if (emitter_.joinable()) {
            clockid_t clock;
            timespec t{};
            if (pthread_getcpuclockid(emitter_.native_handle(), &clock) == 0 &&
                clock_gettime(clock, &t) == 0) {
                char line[96];
                std::snprintf(line, sizeof line, "thread sink emitter CPU ms: %.3f",
                              (t.tv_sec * 1e9 + t.tv_nsec) / 1e6);
                lines.push_back(line);
            }
        }
        {
            std::lock_guard lock(placement_mutex_);
            std::string application = format_cpu_list(placement_.application_cpus);
            if (!placement_.application_siblings.empty())
                application +=
                    "; their SMT siblings: " + format_cpu_list(placement_.application_siblings);
            lines.push_back(
                (placement_.cpus.empty()
                     ? "background threads: with the application (CPUs " + application + ")"
                     : "background threads: asked for CPUs " + format_cpu_list(placement_.cpus) +
                           " (the application's: " + application + ")") +
                "; sink on " + format_cpu_list(sink_cpus_));
        }
        const std::string raised =
            "sink thread raised out of the idle class: " + std::to_string(priority_.raises()) +
            " times" + (priority_.idle_class() ? "" : " (runs at nice 10: cannot leave it)");
        auto write = lock_writer();
        if (!writer_) {
            lines.push_back(raised);
            return lines;
        }
        const traces::TraceWriterStats w = writer_->stats();
        lines.back() +=
            std::string(", compressor ") + (placement_.cpus.empty() ? "as created"
                                            : w.compressor_placed   ? "placed"
                                                                    : "refused (as created)");
        lines.push_back(raised);
        char line[256];
        std::snprintf(line, sizeof line,
                      "trace: %llu records, %llu chunks, %llu raw bytes -> %llu compressed (zstd "
                      "level %d); contents: %llu "
                      "stored (%llu bytes), %llu deduplicated (%llu bytes)",
                      (unsigned long long)w.records, (unsigned long long)w.chunks,
                      (unsigned long long)w.raw_bytes, (unsigned long long)w.compressed_bytes,
                      zstd_level_, (unsigned long long)w.contents_stored,
                      (unsigned long long)w.contents_bytes_stored,
                      (unsigned long long)w.contents_deduplicated,
                      (unsigned long long)w.contents_bytes_deduplicated);
        lines.push_back(line);
        std::snprintf(line, sizeof line,
                      "trace writer ms: contents (hash, dedup, frame) %.3f, compress %.3f, file "
                      "writes %.3f, compressor "
                      "CPU %.3f, appends blocked on the compressor %.3f, flushes waiting %.3f",
                      w.contents_ns / 1e6, w.compress_ns / 1e6, w.file_write_ns / 1e6,
                      w.compressor_cpu_ns / 1e6, w.append_blocked_ns / 1e6, w.flush_wait_ns / 1e6);
        lines.push_back(line);
        return lines;
    }

    // An object's create record waits for its NV handle or KHR address (asked right after
    // binding, or right after creation), so one AccelerationStructureCreate carries it; its
    // binding and memory requirements follow it.
    void acceleration_structure_created(const AccelerationStructureRecord& a) override {
        StateLock lock(*this);
        auto r = std::make_unique<fbs::AccelerationStructureCreateT>();
        r->acceleration_structure = a.acceleration_structure;
        r->api = a.khr ? 1 : 0;
        r->type = a.type;
        r->buffer = a.buffer;
        r->offset = a.offset;
        r->size = a.size;
        r->create_flags = a.create_flags;
        r->compacted_size = a.compacted_size;
        if (!a.khr) r->info = nv_info_of(a.info_type, a.info_flags, a.instance_count, a.geometries);
        pending_objects_[a.acceleration_structure].create = std::move(r);
    }
    void acceleration_structure_bound(const AccelerationStructureBindingRecord& b) override {
        fbs::AccelerationStructureBindMemoryT r;
        r.acceleration_structure = b.acceleration_structure;
        r.memory = b.memory;
        r.memory_offset = b.offset;
        object_record(b.acceleration_structure, record_of(std::move(r)));
    }
    void acceleration_structure_memory_requirements(
        const AccelerationStructureMemoryRequirementsRecord& m) override {
        fbs::AccelerationStructureMemoryRequirementsNVT r;
        r.acceleration_structure = m.acceleration_structure;
        r.type = m.type;
        r.size = m.size;
        r.alignment = m.alignment;
        r.memory_type_bits = m.memory_type_bits;
        object_record(m.acceleration_structure, record_of(std::move(r)));
    }
    void acceleration_structure_address_queried(
        const AccelerationStructureAddressRecord& a) override {
        StateLock lock(*this);
        auto it = pending_objects_.find(a.acceleration_structure);
        if (it == pending_objects_.end() || !it->second.create)
            return;  // created before capture, or asked again
        it->second.create->device_address = a.address;
        emit_object_locked(it);
    }
    void acceleration_structure_destroyed(uint64_t as) override {
        StateLock lock(*this);
        if (auto it = pending_objects_.find(as); it != pending_objects_.end())
            emit_object_locked(it);
        fbs::AccelerationStructureDestroyT r;
        r.acceleration_structure = as;
        // After the submissions announced before it, as a buffer's destroy: a submission still
        // waiting for its captures must not find its structures destroyed before it runs.
        append_ordered_locked(record_of(std::move(r)));
    }
    void ray_query_checked(const RayCheckRecord& c) override {
        StateLock lock(*this);
        if (auto it = pending_.find(c.submission_index); it != pending_.end()) {
            it->second.ray_checks.push_back(c);  // goes out right after its submission
            return;
        }
        if (writer_ && !failed_) outbox_.emplace_back(c);
    }

private:
    struct PendingObject {
        std::unique_ptr<fbs::AccelerationStructureCreateT> create;
        std::vector<fbs::RecordT> after;  // binding, memory requirements
    };

    void object_record(uint64_t as, fbs::RecordT record) {
        StateLock lock(*this);
        auto it = pending_objects_.find(as);
        if (it != pending_objects_.end())
            it->second.after.push_back(std::move(record));
        else
            append_locked(std::move(record));
    }
    void emit_object_locked(std::map<uint64_t, PendingObject>::iterator it) {
        if (it->second.create) append_locked(record_of(std::move(*it->second.create)));
        for (auto& r : it->second.after) append_locked(std::move(r));
        pending_objects_.erase(it);
    }
    void flush_objects_locked() {
        while (!pending_objects_.empty()) emit_object_locked(pending_objects_.begin());
    }
    void write_ray_check(const RayCheckRecord& c) {
        auto index = trace_submission_.find(c.submission_index);
        write_record(record_of(
            ray_query_check_of(c, index == trace_submission_.end() ? ~0ull : index->second)));
    }

    // A record of an application call, or a host write whose bytes the writing side stores.
    using Ordered = std::variant<fbs::RecordT, HostWriteRecord>;
    struct Pending {
        SubmissionRecord submission;
        bool submitted = false;
        size_t expected_builds = 0;
        std::vector<std::shared_ptr<RecordedCommandBuffer>> command_buffers;
        std::map<uint64_t, std::shared_ptr<RecordedCommandBuffer>>
            secondaries;  // executed by them, by handle
        std::map<std::pair<uint64_t, uint32_t>, ClusterBuildCapture>
            builds;                  // by (pauseId, occurrence)
        std::vector<Ordered> after;  // the application's calls made after this submission
        std::vector<RayCheckRecord> ray_checks;
        std::optional<PreRangeStateRecord> pre_range;  // the prelude's (layer_pre_range.cpp)
    };
    // Past this the sink's thread is raised: a sink that lags also holds the images whose regions
    // the served region pool would lend the next pauses (their copies then fault fresh pages).
    static constexpr uint64_t kMaxPendingBytes = 64ull << 20;
    static constexpr uint64_t kHardPendingBytes = 1024ull << 20;  // the deliverer waits
    static constexpr int kBackgroundNice = 10;  // the sink's and the compressor's threads

    // The pause that reads a command buffer's timestamps (0: it has none).
    static uint64_t timestamp_read_of(const RecordedCommandBuffer& cb) {
        for (const auto& c : cb.commands)
            if (const auto* t = std::get_if<TimestampWriteCommand>(&c)) return t->read_pause_id;
        return 0;
    }
    static uint64_t pause_id_of(const RecordedCommand& command) {
        if (const auto* c = std::get_if<ClusterBuildCommand>(&command)) return c->pause_id;
        if (const auto* c = std::get_if<BuildAccelerationStructureNVCommand>(&command))
            return c->pause_id;
        if (const auto* c = std::get_if<CopyMemoryToAccelerationStructureCommand>(&command))
            return c->pause_id;
        if (const auto* c = std::get_if<DispatchCommand>(&command)) return c->pause_id;
        if (const auto* c = std::get_if<BuildAccelerationStructuresKHRCommand>(&command))
            return c->pause_id;
        if (const auto* c = std::get_if<CopyAccelerationStructureCommand>(&command))
            return c->pause_id;
        if (const auto* c = std::get_if<TraceRaysCommand>(&command)) return c->pause_id;
        return 0;
    }

    void wake_emitter() {
        {
            std::lock_guard lock(wake_mutex_);
            work_ = true;
        }
        wake_.notify_one();
    }

    // Emits submissions whose builds all arrived, and every flushMilliseconds_ writes the
    // records so far out as a finished chunk.
    void emit_in_background() {
        emitterThread = true;
        // The application's threads (and the served builds' engine) come first: writing the trace
        // takes the cores they leave idle (SCHED_IDLE; nice 10 where the class could not be left
        // again), except while raised (idle_priority.h).
        priority_.enter_on_calling_thread();
        pthread_setname_np(pthread_self(), "clastrace-sink");  // for profilers and top
        using Clock = std::chrono::steady_clock;
        auto last_flush = Clock::now();
        const auto interval =
            std::chrono::milliseconds(flush_milliseconds_ ? flush_milliseconds_ : 3600000);
        std::unique_lock wait(wake_mutex_);
        while (!stop_emitting_) {
            if (!work_ && pending_bytes_ < kMaxPendingBytes / 2) priority_.settle();
            wake_.wait_until(wait, last_flush + interval, [&] { return stop_emitting_ || work_; });
            if (stop_emitting_) break;
            work_ = false;
            wait.unlock();
            {
                std::lock_guard write(write_mutex_);
                {
                    StateLock lock(*this);
                    emit_ready_locked(false);
                }
                write_outbox_locked();
                if (flush_milliseconds_ && Clock::now() - last_flush >= interval) {
                    CostScope cost(CostPhase::kPeriodicFlush);
                    if (writer_ && !failed_ && appended_since_flush_) check(writer_->flush());
                    appended_since_flush_ = false;
                    last_flush = Clock::now();
                }
            }
            wait.lock();
        }
    }

    void fail(const TraceError& error) {
        if (failed_.exchange(true)) return;
        std::fprintf(stderr,
                     "clastrace: capture stopped: %s; the application continues without capture\n",
                     error.message.c_str());
    }
    bool check(const TraceError& error) {
        if (error) fail(error);
        return !error;
    }
    void append(fbs::RecordT record) {
        StateLock lock(*this);
        append_ordered_locked(std::move(record));
    }
    // writeMutex_ for a thread other than the sink's, which it would wait for: raised first if
    // taken (the sink's thread may hold it in SCHED_IDLE).
    std::unique_lock<std::mutex> lock_writer() {
        std::unique_lock write(write_mutex_, std::try_to_lock);
        if (write.owns_lock()) return write;
        priority_.raise();
        write.lock();
        return write;
    }
    // Past kHardPendingBytes: waits until the sink's thread wrote everything that can be written
    // now (a submission still waiting for its builds cannot be), or the bytes dropped below.
    void wait_until_written() {
        CostScope cost(CostPhase::kSinkBoundWait);
        release_written();  // the pause worker's job, which it cannot do while it waits here
        std::unique_lock lock(mutex_);
        written_pass_.wait(lock, [&] {
            return pending_bytes_ <= kHardPendingBytes || failed_ || !ready_to_write_locked();
        });
    }
    bool ready_to_write_locked() const {
        if (writing_ || !outbox_.empty()) return true;
        if (pending_.empty()) return false;
        const Pending& p = pending_.begin()->second;
        return p.submitted && p.builds.size() >= p.expected_builds;
    }
    // A record of an application call goes after the newest submission announced before it (the
    // call came after that vkQueueSubmit returned); a submission still waiting for its builds
    // holds it back, so the trace keeps the order of the calls.
    void append_ordered_locked(Ordered record) {
        for (auto it = pending_.rbegin(); it != pending_.rend(); ++it)
            if (it->second.submitted) {
                it->second.after.push_back(std::move(record));
                return;
            }
        if (writer_ && !failed_)
            std::visit([&](auto& r) { outbox_.emplace_back(std::move(r)); }, record);
    }
    // Queues a record for the file (mutex_ held); writeOutboxLocked writes it.
    void append_locked(fbs::RecordT record) {
        if (writer_ && !failed_) outbox_.emplace_back(std::move(record));
    }
    void write_record(const fbs::RecordT& record) {  // writeMutex_ held
        if (writer_ && !failed_) check(writer_->append(record));
        appended_since_flush_ = true;
    }
    // Its bytes into the content store, then the record naming them (writeMutex_ held).
    void write_host_write(const HostWriteRecord& w) {
        if (!writer_ || failed_) return;
        fbs::MemoryObservationT r;
        r.memory = w.memory;
        r.memory_offset = w.memory_offset;
        r.reason = uint32_t(w.seen);
        fbs::MemorySnapshot snap;
        if (!check(writer_->snapshot(w.buffer, w.buffer_offset, w.address, w.bytes.data(),
                                     w.bytes.size(), &snap)))
            return;
        r.snapshots.push_back(snap);
        write_record(record_of(std::move(r)));
    }
    void write_ordered(const Ordered& item) {
        if (const auto* record = std::get_if<fbs::RecordT>(&item))
            write_record(*record);
        else
            write_host_write(std::get<HostWriteRecord>(item));
    }
    void emit_bind_locked(const BufferBindingRecord& b, VkDeviceAddress address, bool ordered) {
        fbs::BufferBindMemoryT r;
        r.buffer = b.buffer;
        r.memory = b.memory;
        r.memory_offset = b.offset;
        r.device_address = address;
        if (ordered)
            append_ordered_locked(record_of(std::move(r)));
        else
            append_locked(record_of(std::move(r)));
        bound_at_[b.buffer] = b;
        if (address) addressed_.insert({b.buffer, true});
    }
    // Bindings never followed by an address query; `ordered` as for appendOrderedLocked (false:
    // right now, before the submission being emitted).
    void flush_binds_locked(bool ordered) {
        for (const auto& [buffer, bind] : pending_binds_) emit_bind_locked(bind, 0, ordered);
        pending_binds_.clear();
        flush_objects_locked();
    }

    // Submissions go out in index order, each once all its builds were captured (or, at the
    // end, with what arrived: a build whose pause never came has no snapshots).
    void emit_ready_locked(bool final) {
        while (!pending_.empty()) {
            auto it = pending_.begin();
            Pending& p = it->second;
            if (!p.submitted) {
                if (!final) return;
                pending_.erase(it);  // captures of a submission outside the range, or unannounced
                continue;
            }
            if (!final && p.builds.size() < p.expected_builds) return;
            flush_binds_locked(false);
            if (writer_ && !failed_) outbox_.emplace_back(std::move(p));
            pending_.erase(it);
        }
    }

    // Writes what the outbox holds, in order, until it stays empty; writeMutex_ held, mutex_ not.
    void write_outbox_locked() {
        for (;;) {
            std::deque<OutItem> items;
            {
                StateLock lock(*this);
                items.swap(outbox_);
                writing_ = !items.empty();
            }
            if (items.empty()) {
                written_pass_.notify_all();
                return;
            }
            uint64_t written = 0;
            for (OutItem& item : items) {
                if (auto* record = std::get_if<fbs::RecordT>(&item)) {
                    write_record(*record);
                } else if (auto* w = std::get_if<HostWriteRecord>(&item)) {
                    write_host_write(*w);
                } else if (auto* p = std::get_if<Pending>(&item)) {
                    write_submission(*p);
                    for (const auto& [key, build] : p->builds) written += held_bytes_of(build);
                } else {
                    write_ray_check(std::get<RayCheckRecord>(item));
                }
            }
            // The captured bytes go to the worker to free (releaseWritten) while few are waiting;
            // past that this thread frees them, so memory stays bounded if no worker comes by.
            {
                std::lock_guard lock(written_mutex_);
                if (written_bytes_ + written <= kMaxWrittenBytes) {
                    for (OutItem& item : items)
                        if (auto* p = std::get_if<Pending>(&item))
                            written_.push_back(std::move(p->builds));
                    written_bytes_ += written;
                    written = 0;
                }
            }
            items.clear();  // frees what is left before the count says it is gone
            {
                StateLock lock(*this);
                pending_bytes_ -= std::min(pending_bytes_.load(), written);
                writing_ = false;
            }
            written_pass_.notify_all();
        }
    }

    // Finishes a served build's record (walking its outputs in the engine's image), here on the
    // sink's thread rather than on the pause worker. Its ranges are views into the image, which
    // they keep until the record is written and freed; with no view the image goes back to the
    // served region pool now.
    void complete_build(ClusterBuildCapture& build) {
        if (!build.complete) return;
        const uint64_t before = held_bytes_of(build);
        {
            CostScope cost(CostPhase::kServedRecordCompletion, true);
            auto complete = std::exchange(build.complete, nullptr);
            complete(build);
        }  // (`complete`'s own reference to the image goes with it)
        auto view = [](const CapturedRange& r) { return r.bytes.is_view(); };
        if (std::none_of(build.inputs.begin(), build.inputs.end(), view) &&
            std::none_of(build.outputs.begin(), build.outputs.end(), view))
            build.held_bytes = 0;
        const uint64_t after = held_bytes_of(build);
        StateLock lock(*this);
        pending_bytes_ = pending_bytes_ - std::min(pending_bytes_.load(), before) + after;
    }

    // One snapshot per run of touching or overlapping ranges of one buffer (all read at the same
    // pause, so overlaps hold equal bytes): the same bytes, without a 40-byte descriptor (and an
    // incompressible 8-byte key) per cluster's vertex or index range. Ranges named only by
    // buffer and offset, or in no known buffer, stay as they are.
    void snapshots(const std::vector<CapturedRange>& ranges,
                   std::vector<fbs::MemorySnapshot>& out) {
        CostScope cost(CostPhase::kSnapshot);
        std::vector<const CapturedRange*> order;
        for (const auto& r : ranges) order.push_back(&r);
        std::stable_sort(order.begin(), order.end(),
                         [](const CapturedRange* a, const CapturedRange* b) {
                             return std::tie(a->buffer, a->address) <
                                    std::tie(b->buffer, b->address);
                         });
        std::vector<traces::ContentPiece> pieces;
        for (size_t i = 0; i < order.size();) {
            const CapturedRange& first = *order[i];
            const bool mergeable = first.address != 0 && first.buffer != 0;
            uint64_t end = first.address + first.bytes.size();
            size_t next = i + 1;
            pieces.assign(1, {first.bytes.data(), first.bytes.size()});
            if (mergeable) {
                for (; next < order.size() && order[next]->buffer == first.buffer &&
                       order[next]->address != 0 && order[next]->address <= end;
                     ++next) {
                    const CapturedRange& r = *order[next];
                    const uint64_t r_end = r.address + r.bytes.size();
                    if (r_end > end)
                        pieces.push_back({r.bytes.data() + (r.bytes.size() - (r_end - end)),
                                          size_t(r_end - end)});
                    end = std::max(end, r_end);
                }
            }
            fbs::MemorySnapshot snap;
            if (!writer_ || failed_) return;
            if (!check(writer_->snapshot(first.buffer, first.buffer_offset, first.address, pieces,
                                         &snap)))
                return;
            out.push_back(snap);
            i = next;
        }
    }

    // Where a command buffer's block runs: a primary of the submission, or a secondary at its
    // primary's vkCmdExecuteCommands (findings name both).
    struct ExecutionSite {
        uint64_t primary = 0;        // 0: the block is a primary's own
        uint32_t execute_index = 0;  // index of the primary's vkCmdExecuteCommands
    };
    struct SubmissionEmit {
        Pending& pending;
        std::map<uint64_t, uint32_t>
            executions;  // pauseId -> executions emitted (repeated executions)
        std::map<uint64_t, uint32_t>
            restatements;  // command buffer -> blocks emitted (CommandBufferBegin.restatement)
        std::vector<fbs::CaptureFindingT> findings;
        // Exact mode: what each marked dispatch of this submission wrote (its `submission` is
        // set when written, just before the QueueSubmit).
        std::vector<fbs::DeviceAddressWritesT> address_writes;
    };

    void write_submission(Pending& p) {
        CostScope cost(CostPhase::kEmit, true);
        for (auto& [key, build] : p.builds) complete_build(build);
        if (p.pre_range) {  // captures may have come after the prelude was announced
            p.pre_range->bytes = 0;
            for (const auto& [key, build] : p.builds)
                for (const CapturedRange& r : build.inputs) p.pre_range->bytes += r.bytes.size();
        }
        SubmissionEmit e{p, {}, {}, {}, {}};
        for (const auto& cb : p.command_buffers) {
            // A secondary's block goes before its primary's, once per execution, so every recording
            // is in the trace before the QueueSubmit that runs it (format 1.2).
            uint32_t position = 0;  // the application's index: the layer's timestamps don't count
            for (const RecordedCommand& command : cb->commands) {
                if (const auto* execute = std::get_if<ExecuteCommandsCommand>(&command))
                    for (uint64_t secondary : execute->secondaries)
                        if (auto it = p.secondaries.find(secondary); it != p.secondaries.end())
                            write_command_buffer(e, *it->second, {cb->command_buffer, position});
                position += !std::holds_alternative<TimestampWriteCommand>(command);
            }
            write_command_buffer(e, *cb, {});
        }
        std::vector<fbs::CaptureFindingT>& findings = e.findings;
        if (!writer_ || failed_) return;
        // Ahead of the QueueSubmit: replay runs a submission at its record, so what the run
        // needs (as the command buffers' blocks) comes before it.
        for (fbs::DeviceAddressWritesT& w : e.address_writes) {
            w.submission = writer_->next_submission_index();
            write_record(record_of(std::move(w)));
        }
        if (p.pre_range)
            write_record(
                record_of(pre_range_state_of(*p.pre_range, writer_->next_submission_index())));
        fbs::QueueSubmitT submit = queue_submit_of(p.submission, writer_->next_submission_index());
        trace_submission_[p.submission.index] = submit.submission_index;
        const uint64_t submission = submit.submission_index;
        write_record(record_of(std::move(submit)));
        for (const RayCheckRecord& c : p.ray_checks) write_ray_check(c);
        for (const SubmissionRecord::Note& note : p.submission.notes)
            findings.push_back(submission_note_finding(note));
        for (fbs::CaptureFindingT& f : findings) {
            f.submission = submission;
            write_record(record_of(std::move(f)));
        }
        for (const Ordered& r : p.after) write_ordered(r);
    }

    // One execution of `cb`: Begin (restated when it ran before in this submission), its
    // commands with that execution's snapshots and timestamps, End.
    void write_command_buffer(SubmissionEmit& e, const RecordedCommandBuffer& cb,
                              ExecutionSite site) {
        Pending& p = e.pending;
        fbs::CommandBufferBeginT begin;
        begin.command_buffer = cb.command_buffer;
        begin.flags = cb.usage;
        begin.level = cb.secondary ? 1 : 0;
        begin.restatement = e.restatements[cb.command_buffer]++;
        write_record(record_of(std::move(begin)));
        const ClusterBuildCapture* timestamps = nullptr;  // this execution's ticks
        if (const uint64_t read_pause_id = timestamp_read_of(cb)) {
            auto it = p.builds.find({read_pause_id, e.executions[read_pause_id]++});
            if (it != p.builds.end()) timestamps = &it->second;
        }
        auto finding = [&](fbs::CaptureFindingT f) {
            f.primary_command_buffer = site.primary;
            f.execute_command_index = site.execute_index;
            e.findings.push_back(std::move(f));
        };
        // Commands are named by their index among the application's commands: the timestamps
        // the layer wrote around them don't count (the application never recorded them).
        size_t index = 0;
        for (const RecordedCommand& command : cb.commands) {
            if (const auto* t = std::get_if<TimestampWriteCommand>(&command)) {
                fbs::GpuTimestampT r;
                r.command_buffer = cb.command_buffer;
                r.query_pool = t->query_pool;
                r.query = t->query;
                r.stage_mask = t->stage_mask;
                if (timestamps && t->query < timestamps->timestamp_ticks.size()) {
                    r.ticks = timestamps->timestamp_ticks[t->query];
                    r.ticks_valid = timestamps->timestamp_valid[t->query];
                }
                write_record(record_of(std::move(r)));
                continue;
            }
            if (const auto* execute = std::get_if<ExecuteCommandsCommand>(&command)) {
                fbs::CmdExecuteCommandsT r;
                r.command_buffer = cb.command_buffer;
                r.secondaries = execute->secondaries;
                write_record(record_of(std::move(r)));
                ++index;
                continue;
            }
            const ClusterBuildCapture* captured = nullptr;
            if (const uint64_t pause_id = pause_id_of(command)) {
                auto it = p.builds.find({pause_id, e.executions[pause_id]++});
                if (it != p.builds.end()) captured = &it->second;
            }
            if (captured && captured->kind == CapturedCommandKind::kDeviceAddressWrites) {
                fbs::DeviceAddressWritesT w;
                w.command_buffer = cb.command_buffer;
                w.command_index = uint32_t(index);  // as CaptureFinding.command_index
                w.compared_bytes = captured->compared_bytes;
                snapshots(captured->outputs, w.writes);
                e.address_writes.push_back(std::move(w));
            } else if (captured) {
                std::vector<fbs::CaptureFindingT> found;
                collect_findings(cb.command_buffer, index, *captured, found);
                for (auto& f : found) finding(std::move(f));
            } else if (pause_id_of(command)) {  // emitted at the end without its pause: say so
                finding(uncaptured_command_finding(cb.command_buffer, index));
            }
            write_command(cb.command_buffer, command, captured);
            ++index;
        }
        fbs::CommandBufferEndT end;
        end.command_buffer = cb.command_buffer;
        write_record(record_of(std::move(end)));
    }

    void write_command(uint64_t cb, const RecordedCommand& command,
                       const ClusterBuildCapture* captured) {
        fbs::RecordT record = command_record_of(cb, command);
        if (record.body.type == fbs::RecordBody::NONE) return;
        if (captured) add_snapshots(*captured, record);
        write_record(std::move(record));
    }
    // What a captured command read (and, for cluster builds, wrote), as the trace's snapshots.
    void add_snapshots(const ClusterBuildCapture& captured, fbs::RecordT& record) {
        if (auto* r = record.body.AsCmdBuildClusterAccelerationStructureIndirect()) {
            snapshots(captured.inputs, r->inputs);
            snapshots(captured.outputs, r->outputs);
            for (const ClusterBuildCapture::DriverBvh& d : captured.driver_bvh)
                r->driver_bvh.emplace_back(d.address, d.size);
            r->implicit_object_room = captured.implicit_object_room;
        } else if (auto* r = record.body.AsCmdBuildAccelerationStructureNV()) {
            snapshots(captured.inputs, r->inputs);
        } else if (auto* r = record.body.AsCmdCopyMemoryToAccelerationStructure()) {
            snapshots(captured.inputs, r->inputs);
        } else if (auto* r = record.body.AsCmdBuildAccelerationStructuresKHR()) {
            snapshots(captured.inputs, r->inputs);
            if (r->indirect) set_indirect_ranges(captured.khr_indirect_ranges, *r);
        } else if (auto* r = record.body.AsCmdCopyAccelerationStructure()) {
            snapshots(captured.inputs, r->inputs);
        } else if (auto* r = record.body.AsCmdCopyAccelerationStructureToMemory()) {
            snapshots(captured.inputs, r->inputs);
        } else if (auto* r = record.body.AsCmdTraceRays()) {
            snapshots(captured.inputs, r->inputs);
        }
    }

    // The state lock, timed: the application's threads and the pause worker report their waits
    // (CLASTRACE_STATS); the sink's own thread does not.
    class StateLock {
    public:
        explicit StateLock(TraceCaptureSink& sink) : lock_(sink.mutex_, std::defer_lock) {
            if (emitterThread) {
                lock_.lock();
                return;
            }
            const uint64_t started = wall_ns();
            if (!lock_.try_lock()) {
                sink.priority_.raise();  // it may hold the lock, starved in SCHED_IDLE
                lock_.lock();
            }
            locked_ = wall_ns();
            const uint64_t waited = locked_ - started;
            if (on_layer_thread()) {
                add_cost(CostPhase::kWorkerSinkWait, waited);
                locked_ = 0;
            } else {
                add_cost(CostPhase::kAppSinkWait, waited);
                started_ = started;
            }
        }
        ~StateLock() {
            if (started_) add_cost(CostPhase::kAppSinkCall, wall_ns() - started_);
        }

    private:
        std::unique_lock<std::mutex> lock_;
        uint64_t locked_ = 0, started_ = 0;
    };
    static thread_local bool emitterThread;
    using OutItem = std::variant<fbs::RecordT, Pending, RayCheckRecord, HostWriteRecord>;

    IdlePriority priority_;  // the sink's thread's (before emitter_, which uses it)
    std::mutex mutex_;
    std::condition_variable written_pass_;  // a write pass ended (mutex_)
    bool writing_ = false;                  // a write pass holds items taken from outbox_ (mutex_)
    std::mutex write_mutex_;                // the writer, and what only the writing side touches
    std::deque<OutItem> outbox_;            // records bound for the file, in trace order (mutex_)
    std::string path_;
    int output_fd_;  // opened and locked at the start, until the writer takes it over (writeMutex_)
    int zstd_level_;
    std::unique_ptr<TraceWriter> writer_;
    std::atomic<bool> failed_{false};
    bool appended_since_flush_ = false;
    uint32_t flush_milliseconds_;
    // Captured bytes held in pending_ and written_; changed under mutex_, read without it by the
    // sink's thread deciding whether to settle (under wake_mutex_, which comes after mutex_).
    std::atomic<uint64_t> pending_bytes_{0};
    // Builds already written, their bytes waiting for releaseWritten.
    static constexpr uint64_t kMaxWrittenBytes = 64ull << 20;
    std::mutex written_mutex_;
    std::vector<std::map<std::pair<uint64_t, uint32_t>, ClusterBuildCapture>> written_;
    uint64_t written_bytes_ = 0;
    std::mutex wake_mutex_;  // guards work_ and stopEmitting_
    std::condition_variable wake_;
    bool work_ = false, stop_emitting_ = false;
    const BackgroundPlacement placement_;
    std::mutex placement_mutex_;
    std::vector<unsigned> sink_cpus_;  // the sink thread's CPUs once placed
    std::thread emitter_;
    std::unordered_map<uint64_t, BufferBindingRecord> pending_binds_;
    std::unordered_map<uint64_t, BufferBindingRecord> bound_at_;
    std::unordered_map<uint64_t, bool> addressed_;
    std::unordered_map<uint64_t, std::shared_ptr<RecordedCommandBuffer>> recorded_;
    std::map<uint64_t, Pending> pending_;                // by submission index
    std::optional<PreRangeStateRecord> pre_range_;       // until its prelude is submitted
    std::map<uint64_t, PendingObject> pending_objects_;  // by acceleration structure
    std::map<uint64_t, uint64_t>
        trace_submission_;  // layer submission index -> trace's (writeMutex_)
};

thread_local bool TraceCaptureSink::emitterThread = false;

}  // namespace

std::unique_ptr<CaptureSink> make_trace_capture_sink(const std::string& path, int zstd_level,
                                                     std::string& error,
                                                     uint32_t flush_milliseconds,
                                                     BackgroundPlacement placement,
                                                     int inherited_fd) {
    // Opened and locked here, before any device exists, so an unusable path or another capture
    // writing it is reported at once; nothing is emptied until the writer starts with the first
    // device (the header describes it). The trace is written in place rather than renamed at the
    // end: a killed application still leaves what was flushed at `path`.
    traces::OutputTarget target;
    const int fd = inherited_fd >= 0 ? traces::adopt_output(inherited_fd, path, &target, &error)
                                     : traces::open_output_in_place(path, &target, &error);
    if (fd < 0) return nullptr;
    return std::make_unique<TraceCaptureSink>(path, fd, zstd_level, flush_milliseconds,
                                              std::move(placement));
}

}  // namespace clastrace::capture
