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
// writes it. Lock order: writeMutex_ before mutex_.
#include "clastrace/capture/capture_sink.h"
#include "clastrace/capture/background_cpus.h"

#include "clastrace/capture/capture_cost.h"
#include "trace_record_encoding.h"

#include <clastrace/traces/cluster_conversions.h>

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
  TraceCaptureSink(std::string path, int outputFd, int zstdLevel, uint32_t flushMilliseconds,
                   BackgroundPlacement placement)
      : path_(std::move(path)), outputFd_(outputFd), zstdLevel_(zstdLevel), flushMilliseconds_(flushMilliseconds),
        placement_(std::move(placement)) {
    emitter_ = std::thread([this] { emitInBackground(); });
  }
  ~TraceCaptureSink() override {
    {
      std::lock_guard lock(wakeMutex_);
      stopEmitting_ = true;
    }
    wake_.notify_all();
    emitter_.join();
    std::lock_guard write(writeMutex_);
    {
      StateLock lock(*this);
      emitReadyLocked(true);
    }
    writeOutboxLocked();
    if (writer_ && !failed_) check(writer_->finish());
    if (outputFd_ >= 0) ::close(outputFd_);  // no device came: the output was left untouched
  }
  bool active() const override { return !failed_; }

  void deviceCreated(const DeviceRecord& d) override {
    std::lock_guard write(writeMutex_);
    StateLock lock(*this);
    if (writer_ || failed_) return;  // the header describes the first device
    const fbs::TraceHeaderT header =
        traceHeaderOf(d, uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                      std::chrono::system_clock::now().time_since_epoch())
                                      .count()));
    traces::TraceWriterOptions options;
    options.zstd_level = zstdLevel_;
    options.compressor_nice = kBackgroundNice;
    options.compressor_idle_class = true;
    options.compressor_cpus = placement_.cpus;
    TraceError error;
    writer_ = TraceWriter::create_on(std::exchange(outputFd_, -1), path_, header, options, &error);
    if (!writer_) fail(error);
  }
  void deviceDestroyed(uint64_t) override {}

  void memoryAllocated(const MemoryRecord& m) override {
    fbs::MemoryAllocateT r;
    r.memory = m.memory;
    r.size = m.size;
    r.memory_type_index = m.typeIndex;
    r.allocate_flags = m.allocateFlags;
    append(recordOf(std::move(r)));
  }
  void memoryFreed(uint64_t memory) override {
    fbs::MemoryFreeT r;
    r.memory = memory;
    append(recordOf(std::move(r)));
  }
  void bufferCreated(const BufferRecord& b) override {
    fbs::BufferCreateT r;
    r.buffer = b.buffer;
    r.size = b.size;
    r.usage = b.usage;
    r.create_flags = b.flags;
    r.sharing_mode = uint32_t(b.sharingMode);
    r.queue_family_indices = b.queueFamilies;
    append(recordOf(std::move(r)));
  }
  // The binding is held back until the application asks for the address (it normally does
  // right after binding), so one BufferBindMemory carries both.
  void bufferBound(const BufferBindingRecord& b) override {
    StateLock lock(*this);
    pendingBinds_[b.buffer] = b;
  }
  void bufferAddressQueried(const BufferAddressRecord& a) override {
    StateLock lock(*this);
    auto it = pendingBinds_.find(a.buffer);
    if (it == pendingBinds_.end()) {
      if (addressed_.count(a.buffer)) return;  // asked again: nothing new
      // Bound before capture saw it, or asked twice after an emitted bind: restate the binding.
      auto known = boundAt_.find(a.buffer);
      if (known == boundAt_.end()) return;
      emitBindLocked(known->second, a.address, true);
      return;
    }
    emitBindLocked(it->second, a.address, true);
    pendingBinds_.erase(it);
  }
  void bufferDestroyed(uint64_t buffer) override {
    StateLock lock(*this);
    flushBindsLocked(true);
    addressed_.erase(buffer);
    boundAt_.erase(buffer);
    fbs::BufferDestroyT r;
    r.buffer = buffer;
    appendOrderedLocked(recordOf(std::move(r)));
  }
  void buildSizesQueried(const BuildSizesQuery& q) override {
    fbs::GetClusterBuildSizesT r;
    r.input = traces::cluster_input_to_record(q.input.resolved().input);
    r.acceleration_structure_size = q.answer.accelerationStructureSize;
    r.update_scratch_size = q.answer.updateScratchSize;
    r.build_scratch_size = q.answer.buildScratchSize;
    append(recordOf(std::move(r)));
  }
  void commandBufferRecorded(const RecordedCommandBuffer& cb) override {
    auto copy = std::make_shared<RecordedCommandBuffer>(cb);  // outside the lock
    StateLock lock(*this);
    recorded_[cb.commandBuffer] = std::move(copy);
  }
  void commandBufferReset(uint64_t) override {}  // each submission restates its command buffers

  void queueSubmitted(const SubmissionRecord& s) override {
    StateLock lock(*this);
    Pending& p = pending_[s.index];
    p.submission = s;
    p.submitted = true;
    for (const auto& batch : s.batches)
      for (uint64_t cb : batch.commandBuffers) {
        auto it = recorded_.find(cb);
        if (it == recorded_.end()) continue;
        p.commandBuffers.push_back(it->second);
        p.expectedBuilds += capturedCommandsOf(*it->second);
        if (timestampReadOf(*it->second)) ++p.expectedBuilds;  // its timestamps' readback
        // Its secondaries as they are now: the application may re-record them once this
        // submission completed, before the sink writes it.
        for (const auto& c : it->second->commands)
          if (const auto* execute = std::get_if<ExecuteCommandsCommand>(&c))
            for (uint64_t secondary : execute->secondaries)
              if (auto found = recorded_.find(secondary); found != recorded_.end()) {
                p.secondaries.emplace(secondary, found->second);
                p.expectedBuilds += capturedCommandsOf(*found->second);
              }
      }
    wakeEmitter();
  }
  // What a captured build holds until it is written: its ranges' own bytes and the served
  // engine image that its unfinished completion or its output views keep.
  static uint64_t heldBytesOf(const ClusterBuildCapture& c) {
    uint64_t bytes = c.heldBytes;
    for (const auto* list : {&c.inputs, &c.outputs})
      for (const CapturedRange& r : *list) bytes += r.bytes.ownedSize();
    return bytes;
  }
  // Commands of `cb` whose execution the worker captures at a pause.
  static size_t capturedCommandsOf(const RecordedCommandBuffer& cb) {
    size_t n = 0;
    for (const auto& c : cb.commands) n += pauseIdOf(c) != 0;
    return n;
  }
  // Hashing and framing the snapshots happen on the sink's thread, not in the pause that
  // delivered them; past kMaxPendingBytes the deliverer does it (bounded memory).
  void clusterBuildCaptured(ClusterBuildCapture c) override {
    bool overLimit = false;
    {
      StateLock lock(*this);
      pendingBytes_ += heldBytesOf(c);
      pending_[c.submissionIndex].builds[{c.pauseId, c.occurrence}] = std::move(c);
      overLimit = pendingBytes_ > kMaxPendingBytes;
      if (overLimit) emitReadyLocked(false);
    }
    if (!overLimit) return wakeEmitter();
    std::lock_guard write(writeMutex_);
    writeOutboxLocked();
  }
  // Host synchronization goes out after the newest submission already announced, as the
  // application made the call after that vkQueueSubmit returned; a submission still waiting
  // for its builds holds it back with it, so the order in the trace is the order of the calls.
  void hostSynchronized(const HostSyncRecord& h) override {
    fbs::RecordT record = hostSyncRecordOf(h);
    StateLock lock(*this);
    appendOrderedLocked(std::move(record));
  }
  // Ordered like host synchronization: after the submissions of the frame it ends.
  void queuePresented(const PresentRecord& p) override {
    fbs::QueuePresentT r;
    r.queue = p.queue;
    r.frame = p.frame;
    r.wait_semaphores = p.waitSemaphores;
    r.swapchains = p.swapchains;
    r.image_indices = p.imageIndices;
    r.result = p.result;
    append(recordOf(std::move(r)));
  }
  // Ordered like presents: the submission that waits on the semaphore comes after it.
  void imageAcquired(const AcquireRecord& a) override {
    fbs::AcquireNextImageT r;
    r.swapchain = a.swapchain;
    r.timeout = a.timeout;
    r.semaphore = a.semaphore;
    r.fence = a.fence;
    r.image_index = a.imageIndex;
    r.result = a.result;
    r.device_mask = a.deviceMask;
    append(recordOf(std::move(r)));
  }
  void releaseWritten() override {
    std::vector<decltype(Pending::builds)> written;
    uint64_t bytes = 0;
    {
      std::lock_guard lock(writtenMutex_);
      if (written_.empty()) return;
      written.swap(written_);
      bytes = writtenBytes_;
      writtenBytes_ = 0;
    }
    written.clear();
    StateLock lock(*this);
    pendingBytes_ -= std::min(pendingBytes_, bytes);
  }
  void flush() override {
    CostScope cost(CostPhase::DeviceFlush, true);
    std::lock_guard write(writeMutex_);
    {
      StateLock lock(*this);
      emitReadyLocked(false);
      flushBindsLocked(false);
    }
    writeOutboxLocked();
    if (writer_ && !failed_) check(writer_->flush());
  }
  std::vector<std::string> costLines() override {
    std::vector<std::string> lines;
    if (emitter_.joinable()) {
      clockid_t clock;
      timespec t{};
      if (pthread_getcpuclockid(emitter_.native_handle(), &clock) == 0 && clock_gettime(clock, &t) == 0) {
        char line[96];
        std::snprintf(line, sizeof line, "thread sink emitter CPU ms: %.3f", (t.tv_sec * 1e9 + t.tv_nsec) / 1e6);
        lines.push_back(line);
      }
    }
    {
      std::lock_guard lock(placementMutex_);
      const std::string application = formatCpuList(placement_.applicationCpus);
      lines.push_back((placement_.cpus.empty()
                           ? "background threads: with the application (CPUs " + application + ")"
                           : "background threads: asked for CPUs " + formatCpuList(placement_.cpus) +
                                 " (the application's: " + application + ")") +
                      "; sink on " + formatCpuList(sinkCpus_));
    }
    std::lock_guard write(writeMutex_);
    if (!writer_) return lines;
    const traces::TraceWriterStats w = writer_->stats();
    lines.back() += std::string(", compressor ") +
                    (placement_.cpus.empty() ? "as created" : w.compressor_placed ? "placed" : "refused (as created)");
    char line[256];
    std::snprintf(line, sizeof line,
                  "trace: %llu records, %llu chunks, %llu raw bytes -> %llu compressed (zstd level %d); contents: %llu "
                  "stored (%llu bytes), %llu deduplicated (%llu bytes)",
                  (unsigned long long)w.records, (unsigned long long)w.chunks, (unsigned long long)w.raw_bytes,
                  (unsigned long long)w.compressed_bytes, zstdLevel_, (unsigned long long)w.contents_stored,
                  (unsigned long long)w.contents_bytes_stored, (unsigned long long)w.contents_deduplicated,
                  (unsigned long long)w.contents_bytes_deduplicated);
    lines.push_back(line);
    std::snprintf(line, sizeof line,
                  "trace writer ms: contents (hash, dedup, frame) %.3f, compress %.3f, file writes %.3f, compressor "
                  "CPU %.3f, appends blocked on the compressor %.3f, flushes waiting %.3f",
                  w.contents_ns / 1e6, w.compress_ns / 1e6, w.file_write_ns / 1e6, w.compressor_cpu_ns / 1e6,
                  w.append_blocked_ns / 1e6, w.flush_wait_ns / 1e6);
    lines.push_back(line);
    return lines;
  }

  // An object's create record waits for its NV handle or KHR address (asked right after
  // binding, or right after creation), so one AccelerationStructureCreate carries it; its
  // binding and memory requirements follow it.
  void accelerationStructureCreated(const AccelerationStructureRecord& a) override {
    StateLock lock(*this);
    auto r = std::make_unique<fbs::AccelerationStructureCreateT>();
    r->acceleration_structure = a.accelerationStructure;
    r->api = a.khr ? 1 : 0;
    r->type = a.type;
    r->buffer = a.buffer;
    r->offset = a.offset;
    r->size = a.size;
    r->create_flags = a.createFlags;
    r->compacted_size = a.compactedSize;
    if (!a.khr) r->info = nvInfoOf(a.infoType, a.infoFlags, a.instanceCount, a.geometries);
    pendingObjects_[a.accelerationStructure].create = std::move(r);
  }
  void accelerationStructureBound(const AccelerationStructureBindingRecord& b) override {
    fbs::AccelerationStructureBindMemoryT r;
    r.acceleration_structure = b.accelerationStructure;
    r.memory = b.memory;
    r.memory_offset = b.offset;
    objectRecord(b.accelerationStructure, recordOf(std::move(r)));
  }
  void accelerationStructureMemoryRequirements(const AccelerationStructureMemoryRequirementsRecord& m) override {
    fbs::AccelerationStructureMemoryRequirementsNVT r;
    r.acceleration_structure = m.accelerationStructure;
    r.type = m.type;
    r.size = m.size;
    r.alignment = m.alignment;
    r.memory_type_bits = m.memoryTypeBits;
    objectRecord(m.accelerationStructure, recordOf(std::move(r)));
  }
  void accelerationStructureAddressQueried(const AccelerationStructureAddressRecord& a) override {
    StateLock lock(*this);
    auto it = pendingObjects_.find(a.accelerationStructure);
    if (it == pendingObjects_.end() || !it->second.create) return;  // created before capture, or asked again
    it->second.create->device_address = a.address;
    emitObjectLocked(it);
  }
  void accelerationStructureDestroyed(uint64_t as) override {
    StateLock lock(*this);
    if (auto it = pendingObjects_.find(as); it != pendingObjects_.end()) emitObjectLocked(it);
    fbs::AccelerationStructureDestroyT r;
    r.acceleration_structure = as;
    appendLocked(recordOf(std::move(r)));
  }
  void rayQueryChecked(const RayCheckRecord& c) override {
    StateLock lock(*this);
    if (auto it = pending_.find(c.submissionIndex); it != pending_.end()) {
      it->second.rayChecks.push_back(c);  // goes out right after its submission
      return;
    }
    if (writer_ && !failed_) outbox_.emplace_back(c);
  }

 private:
  struct PendingObject {
    std::unique_ptr<fbs::AccelerationStructureCreateT> create;
    std::vector<fbs::RecordT> after;  // binding, memory requirements
  };

  void objectRecord(uint64_t as, fbs::RecordT record) {
    StateLock lock(*this);
    auto it = pendingObjects_.find(as);
    if (it != pendingObjects_.end()) it->second.after.push_back(std::move(record));
    else appendLocked(std::move(record));
  }
  void emitObjectLocked(std::map<uint64_t, PendingObject>::iterator it) {
    if (it->second.create) appendLocked(recordOf(std::move(*it->second.create)));
    for (auto& r : it->second.after) appendLocked(std::move(r));
    pendingObjects_.erase(it);
  }
  void flushObjectsLocked() {
    while (!pendingObjects_.empty()) emitObjectLocked(pendingObjects_.begin());
  }
  void writeRayCheck(const RayCheckRecord& c) {
    auto index = traceSubmission_.find(c.submissionIndex);
    writeRecord(recordOf(rayQueryCheckOf(c, index == traceSubmission_.end() ? ~0ull : index->second)));
  }

  struct Pending {
    SubmissionRecord submission;
    bool submitted = false;
    size_t expectedBuilds = 0;
    std::vector<std::shared_ptr<RecordedCommandBuffer>> commandBuffers;
    std::map<uint64_t, std::shared_ptr<RecordedCommandBuffer>> secondaries;  // executed by them, by handle
    std::map<std::pair<uint64_t, uint32_t>, ClusterBuildCapture> builds;  // by (pauseId, occurrence)
    std::vector<fbs::RecordT> after;  // the application's calls made after this submission
    std::vector<RayCheckRecord> rayChecks;
  };
  static constexpr uint64_t kMaxPendingBytes = 256ull << 20;
  static constexpr int kBackgroundNice = 10;  // the sink's and the compressor's threads

  // The pause that reads a command buffer's timestamps (0: it has none).
  static uint64_t timestampReadOf(const RecordedCommandBuffer& cb) {
    for (const auto& c : cb.commands)
      if (const auto* t = std::get_if<TimestampWriteCommand>(&c)) return t->readPauseId;
    return 0;
  }
  static uint64_t pauseIdOf(const RecordedCommand& command) {
    if (const auto* c = std::get_if<ClusterBuildCommand>(&command)) return c->pauseId;
    if (const auto* c = std::get_if<BuildAccelerationStructureNVCommand>(&command)) return c->pauseId;
    if (const auto* c = std::get_if<CopyMemoryToAccelerationStructureCommand>(&command)) return c->pauseId;
    return 0;
  }

  void wakeEmitter() {
    {
      std::lock_guard lock(wakeMutex_);
      work_ = true;
    }
    wake_.notify_one();
  }

  // Emits submissions whose builds all arrived, and every flushMilliseconds_ writes the
  // records so far out as a finished chunk.
  void emitInBackground() {
    emitterThread = true;
    // The application's threads (and the served builds' engine) come first: writing the trace
    // takes the cores they leave idle (SCHED_IDLE; a lower nice where the class is refused).
    // Memory stays bounded (kMaxPendingBytes: past it the pause worker writes itself, at its
    // own priority). Best effort, per thread on Linux.
    sched_param idle{};
    if (pthread_setschedparam(pthread_self(), SCHED_IDLE, &idle) != 0)
      (void)setpriority(PRIO_PROCESS, id_t(gettid()), kBackgroundNice);
    pthread_setname_np(pthread_self(), "clastrace-sink");  // for profilers and top
    if (!placement_.cpus.empty()) (void)placeCallingThread(placement_.cpus);
    {
      std::lock_guard lock(placementMutex_);
      sinkCpus_ = callingThreadCpus();  // what the kernel gave, for the stats line
    }
    using Clock = std::chrono::steady_clock;
    auto lastFlush = Clock::now();
    const auto interval = std::chrono::milliseconds(flushMilliseconds_ ? flushMilliseconds_ : 3600000);
    std::unique_lock wait(wakeMutex_);
    while (!stopEmitting_) {
      wake_.wait_until(wait, lastFlush + interval, [&] { return stopEmitting_ || work_; });
      if (stopEmitting_) break;
      work_ = false;
      wait.unlock();
      {
        std::lock_guard write(writeMutex_);
        {
          StateLock lock(*this);
          emitReadyLocked(false);
        }
        writeOutboxLocked();
        if (flushMilliseconds_ && Clock::now() - lastFlush >= interval) {
          CostScope cost(CostPhase::PeriodicFlush);
          if (writer_ && !failed_ && appendedSinceFlush_) check(writer_->flush());
          appendedSinceFlush_ = false;
          lastFlush = Clock::now();
        }
      }
      wait.lock();
    }
  }

  void fail(const TraceError& error) {
    if (failed_.exchange(true)) return;
    std::fprintf(stderr, "clastrace: capture stopped: %s; the application continues without capture\n",
                 error.message.c_str());
  }
  bool check(const TraceError& error) {
    if (error) fail(error);
    return !error;
  }
  void append(fbs::RecordT record) {
    StateLock lock(*this);
    appendOrderedLocked(std::move(record));
  }
  // A record of an application call goes after the newest submission announced before it (the
  // call came after that vkQueueSubmit returned); a submission still waiting for its builds
  // holds it back, so the trace keeps the order of the calls.
  void appendOrderedLocked(fbs::RecordT record) {
    for (auto it = pending_.rbegin(); it != pending_.rend(); ++it)
      if (it->second.submitted) {
        it->second.after.push_back(std::move(record));
        return;
      }
    appendLocked(std::move(record));
  }
  // Queues a record for the file (mutex_ held); writeOutboxLocked writes it.
  void appendLocked(fbs::RecordT record) {
    if (writer_ && !failed_) outbox_.emplace_back(std::move(record));
  }
  void writeRecord(const fbs::RecordT& record) {  // writeMutex_ held
    if (writer_ && !failed_) check(writer_->append(record));
    appendedSinceFlush_ = true;
  }
  void emitBindLocked(const BufferBindingRecord& b, VkDeviceAddress address, bool ordered) {
    fbs::BufferBindMemoryT r;
    r.buffer = b.buffer;
    r.memory = b.memory;
    r.memory_offset = b.offset;
    r.device_address = address;
    if (ordered) appendOrderedLocked(recordOf(std::move(r)));
    else appendLocked(recordOf(std::move(r)));
    boundAt_[b.buffer] = b;
    if (address) addressed_.insert({b.buffer, true});
  }
  // Bindings never followed by an address query; `ordered` as for appendOrderedLocked (false:
  // right now, before the submission being emitted).
  void flushBindsLocked(bool ordered) {
    for (const auto& [buffer, bind] : pendingBinds_) emitBindLocked(bind, 0, ordered);
    pendingBinds_.clear();
    flushObjectsLocked();
  }

  // Submissions go out in index order, each once all its builds were captured (or, at the
  // end, with what arrived: a build whose pause never came has no snapshots).
  void emitReadyLocked(bool final) {
    while (!pending_.empty()) {
      auto it = pending_.begin();
      Pending& p = it->second;
      if (!p.submitted) {
        if (!final) return;
        pending_.erase(it);  // captures of a submission outside the range, or unannounced
        continue;
      }
      if (!final && p.builds.size() < p.expectedBuilds) return;
      flushBindsLocked(false);
      if (writer_ && !failed_) outbox_.emplace_back(std::move(p));
      pending_.erase(it);
    }
  }

  // Writes what the outbox holds, in order, until it stays empty; writeMutex_ held, mutex_ not.
  void writeOutboxLocked() {
    for (;;) {
      std::deque<OutItem> items;
      {
        StateLock lock(*this);
        items.swap(outbox_);
      }
      if (items.empty()) return;
      uint64_t written = 0;
      for (OutItem& item : items) {
        if (auto* record = std::get_if<fbs::RecordT>(&item)) {
          writeRecord(*record);
        } else if (auto* p = std::get_if<Pending>(&item)) {
          writeSubmission(*p);
          for (const auto& [key, build] : p->builds) written += heldBytesOf(build);
        } else {
          writeRayCheck(std::get<RayCheckRecord>(item));
        }
      }
      // The captured bytes go to the worker to free (releaseWritten) while few are waiting;
      // past that this thread frees them, so memory stays bounded if no worker comes by.
      {
        std::lock_guard lock(writtenMutex_);
        if (writtenBytes_ + written <= kMaxWrittenBytes) {
          for (OutItem& item : items)
            if (auto* p = std::get_if<Pending>(&item)) written_.push_back(std::move(p->builds));
          writtenBytes_ += written;
          written = 0;
        }
      }
      items.clear();  // frees what is left before the count says it is gone
      StateLock lock(*this);
      pendingBytes_ -= std::min(pendingBytes_, written);
    }
  }

  // Finishes a served build's record (walking its outputs in the engine's image), here on the
  // sink's thread rather than on the pause worker. Its ranges are views into the image, which
  // they keep until the record is written and freed; with no view the image goes back to the
  // served region pool now.
  void completeBuild(ClusterBuildCapture& build) {
    if (!build.complete) return;
    const uint64_t before = heldBytesOf(build);
    {
      CostScope cost(CostPhase::ServedRecordCompletion, true);
      auto complete = std::exchange(build.complete, nullptr);
      complete(build);
    }  // (`complete`'s own reference to the image goes with it)
    auto view = [](const CapturedRange& r) { return r.bytes.isView(); };
    if (std::none_of(build.inputs.begin(), build.inputs.end(), view) &&
        std::none_of(build.outputs.begin(), build.outputs.end(), view))
      build.heldBytes = 0;
    const uint64_t after = heldBytesOf(build);
    StateLock lock(*this);
    pendingBytes_ = pendingBytes_ - std::min(pendingBytes_, before) + after;
  }

  // One snapshot per run of touching or overlapping ranges of one buffer (all read at the same
  // pause, so overlaps hold equal bytes): the same bytes, without a 40-byte descriptor (and an
  // incompressible 8-byte key) per cluster's vertex or index range. Ranges named only by
  // buffer and offset, or in no known buffer, stay as they are.
  void snapshots(const std::vector<CapturedRange>& ranges, std::vector<fbs::MemorySnapshot>& out) {
    CostScope cost(CostPhase::Snapshot);
    std::vector<const CapturedRange*> order;
    for (const auto& r : ranges) order.push_back(&r);
    std::stable_sort(order.begin(), order.end(), [](const CapturedRange* a, const CapturedRange* b) {
      return std::tie(a->buffer, a->address) < std::tie(b->buffer, b->address);
    });
    std::vector<traces::ContentPiece> pieces;
    for (size_t i = 0; i < order.size();) {
      const CapturedRange& first = *order[i];
      const bool mergeable = first.address != 0 && first.buffer != 0;
      uint64_t end = first.address + first.bytes.size();
      size_t next = i + 1;
      pieces.assign(1, {first.bytes.data(), first.bytes.size()});
      if (mergeable) {
        for (; next < order.size() && order[next]->buffer == first.buffer && order[next]->address != 0 &&
               order[next]->address <= end;
             ++next) {
          const CapturedRange& r = *order[next];
          const uint64_t rEnd = r.address + r.bytes.size();
          if (rEnd > end) pieces.push_back({r.bytes.data() + (r.bytes.size() - (rEnd - end)), size_t(rEnd - end)});
          end = std::max(end, rEnd);
        }
      }
      fbs::MemorySnapshot snap;
      if (!writer_ || failed_) return;
      if (!check(writer_->snapshot(first.buffer, first.bufferOffset, first.address, pieces, &snap))) return;
      out.push_back(snap);
      i = next;
    }
  }

  // Where a command buffer's block runs: a primary of the submission, or a secondary at its
  // primary's vkCmdExecuteCommands (findings name both).
  struct ExecutionSite {
    uint64_t primary = 0;        // 0: the block is a primary's own
    uint32_t executeIndex = 0;   // index of the primary's vkCmdExecuteCommands
  };
  struct SubmissionEmit {
    Pending& pending;
    std::map<uint64_t, uint32_t> executions;   // pauseId -> executions emitted (repeated executions)
    std::map<uint64_t, uint32_t> restatements;  // command buffer -> blocks emitted (CommandBufferBegin.restatement)
    std::vector<fbs::CaptureFindingT> findings;
  };

  void writeSubmission(Pending& p) {
    CostScope cost(CostPhase::Emit, true);
    for (auto& [key, build] : p.builds) completeBuild(build);
    SubmissionEmit e{p, {}, {}, {}};
    for (const auto& cb : p.commandBuffers) {
      // A secondary's block goes before its primary's, once per execution, so every recording
      // is in the trace before the QueueSubmit that runs it (format 1.2).
      for (size_t index = 0; index < cb->commands.size(); ++index)
        if (const auto* execute = std::get_if<ExecuteCommandsCommand>(&cb->commands[index]))
          for (uint64_t secondary : execute->secondaries)
            if (auto it = p.secondaries.find(secondary); it != p.secondaries.end())
              writeCommandBuffer(e, *it->second, {cb->commandBuffer, uint32_t(index)});
      writeCommandBuffer(e, *cb, {});
    }
    std::vector<fbs::CaptureFindingT>& findings = e.findings;
    if (!writer_ || failed_) return;
    fbs::QueueSubmitT submit = queueSubmitOf(p.submission, writer_->next_submission_index());
    traceSubmission_[p.submission.index] = submit.submission_index;
    const uint64_t submission = submit.submission_index;
    writeRecord(recordOf(std::move(submit)));
    for (const RayCheckRecord& c : p.rayChecks) writeRayCheck(c);
    for (const SubmissionRecord::Note& note : p.submission.notes) findings.push_back(submissionNoteFinding(note));
    for (fbs::CaptureFindingT& f : findings) {
      f.submission = submission;
      writeRecord(recordOf(std::move(f)));
    }
    for (const fbs::RecordT& r : p.after) writeRecord(r);
  }

  // One execution of `cb`: Begin (restated when it ran before in this submission), its
  // commands with that execution's snapshots and timestamps, End.
  void writeCommandBuffer(SubmissionEmit& e, const RecordedCommandBuffer& cb, ExecutionSite site) {
    Pending& p = e.pending;
    fbs::CommandBufferBeginT begin;
    begin.command_buffer = cb.commandBuffer;
    begin.flags = cb.usage;
    begin.level = cb.secondary ? 1 : 0;
    begin.restatement = e.restatements[cb.commandBuffer]++;
    writeRecord(recordOf(std::move(begin)));
    const ClusterBuildCapture* timestamps = nullptr;  // this execution's ticks
    if (const uint64_t readPauseId = timestampReadOf(cb)) {
      auto it = p.builds.find({readPauseId, e.executions[readPauseId]++});
      if (it != p.builds.end()) timestamps = &it->second;
    }
    auto finding = [&](fbs::CaptureFindingT f) {
      f.primary_command_buffer = site.primary;
      f.execute_command_index = site.executeIndex;
      e.findings.push_back(std::move(f));
    };
    for (size_t index = 0; index < cb.commands.size(); ++index) {
      const RecordedCommand& command = cb.commands[index];
      if (const auto* t = std::get_if<TimestampWriteCommand>(&command)) {
        fbs::GpuTimestampT r;
        r.command_buffer = cb.commandBuffer;
        r.query_pool = t->queryPool;
        r.query = t->query;
        r.stage_mask = t->stageMask;
        if (timestamps && t->query < timestamps->timestampTicks.size()) {
          r.ticks = timestamps->timestampTicks[t->query];
          r.ticks_valid = timestamps->timestampValid[t->query];
        }
        writeRecord(recordOf(std::move(r)));
        continue;
      }
      if (const auto* execute = std::get_if<ExecuteCommandsCommand>(&command)) {
        fbs::CmdExecuteCommandsT r;
        r.command_buffer = cb.commandBuffer;
        r.secondaries = execute->secondaries;
        writeRecord(recordOf(std::move(r)));
        continue;
      }
      const ClusterBuildCapture* captured = nullptr;
      if (const uint64_t pauseId = pauseIdOf(command)) {
        auto it = p.builds.find({pauseId, e.executions[pauseId]++});
        if (it != p.builds.end()) captured = &it->second;
      }
      if (captured) {
        std::vector<fbs::CaptureFindingT> found;
        collectFindings(cb.commandBuffer, index, *captured, found);
        for (auto& f : found) finding(std::move(f));
      } else if (pauseIdOf(command)) {  // emitted at the end without its pause: say so
        finding(uncapturedCommandFinding(cb.commandBuffer, index));
      }
      writeCommand(cb.commandBuffer, command, captured);
    }
    fbs::CommandBufferEndT end;
    end.command_buffer = cb.commandBuffer;
    writeRecord(recordOf(std::move(end)));
  }

  void writeCommand(uint64_t cb, const RecordedCommand& command, const ClusterBuildCapture* captured) {
    fbs::RecordT record = commandRecordOf(cb, command);
    if (record.body.type == fbs::RecordBody::NONE) return;
    if (captured) addSnapshots(*captured, record);
    writeRecord(std::move(record));
  }
  // What a captured command read (and, for cluster builds, wrote), as the trace's snapshots.
  void addSnapshots(const ClusterBuildCapture& captured, fbs::RecordT& record) {
    if (auto* r = record.body.AsCmdBuildClusterAccelerationStructureIndirect()) {
      snapshots(captured.inputs, r->inputs);
      snapshots(captured.outputs, r->outputs);
    } else if (auto* r = record.body.AsCmdBuildAccelerationStructureNV()) {
      snapshots(captured.inputs, r->inputs);
    } else if (auto* r = record.body.AsCmdCopyMemoryToAccelerationStructure()) {
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
      const uint64_t started = wallNs();
      lock_.lock();
      locked_ = wallNs();
      const uint64_t waited = locked_ - started;
      if (onLayerThread()) {
        addCost(CostPhase::WorkerSinkWait, waited);
        locked_ = 0;
      } else {
        addCost(CostPhase::AppSinkWait, waited);
        started_ = started;
      }
    }
    ~StateLock() {
      if (started_) addCost(CostPhase::AppSinkCall, wallNs() - started_);
    }

   private:
    std::unique_lock<std::mutex> lock_;
    uint64_t locked_ = 0, started_ = 0;
  };
  static thread_local bool emitterThread;
  using OutItem = std::variant<fbs::RecordT, Pending, RayCheckRecord>;

  std::mutex mutex_;
  std::mutex writeMutex_;     // the writer, and what only the writing side touches
  std::deque<OutItem> outbox_;  // records bound for the file, in trace order (mutex_)
  std::string path_;
  int outputFd_;  // opened and locked at the start, until the writer takes it over (writeMutex_)
  int zstdLevel_;
  std::unique_ptr<TraceWriter> writer_;
  std::atomic<bool> failed_{false};
  bool appendedSinceFlush_ = false;
  uint32_t flushMilliseconds_;
  uint64_t pendingBytes_ = 0;  // captured bytes held in pending_ and written_
  // Builds already written, their bytes waiting for releaseWritten.
  static constexpr uint64_t kMaxWrittenBytes = 64ull << 20;
  std::mutex writtenMutex_;
  std::vector<std::map<std::pair<uint64_t, uint32_t>, ClusterBuildCapture>> written_;
  uint64_t writtenBytes_ = 0;
  std::mutex wakeMutex_;       // guards work_ and stopEmitting_
  std::condition_variable wake_;
  bool work_ = false, stopEmitting_ = false;
  const BackgroundPlacement placement_;
  std::mutex placementMutex_;
  std::vector<unsigned> sinkCpus_;  // the sink thread's CPUs once placed
  std::thread emitter_;
  std::unordered_map<uint64_t, BufferBindingRecord> pendingBinds_;
  std::unordered_map<uint64_t, BufferBindingRecord> boundAt_;
  std::unordered_map<uint64_t, bool> addressed_;
  std::unordered_map<uint64_t, std::shared_ptr<RecordedCommandBuffer>> recorded_;
  std::map<uint64_t, Pending> pending_;  // by submission index
  std::map<uint64_t, PendingObject> pendingObjects_;  // by acceleration structure
  std::map<uint64_t, uint64_t> traceSubmission_;     // layer submission index -> trace's (writeMutex_)
};

thread_local bool TraceCaptureSink::emitterThread = false;

}  // namespace

std::unique_ptr<CaptureSink> makeTraceCaptureSink(const std::string& path, int zstdLevel, std::string& error,
                                                  uint32_t flushMilliseconds, BackgroundPlacement placement,
                                                  int inheritedFd) {
  // Opened and locked here, before any device exists, so an unusable path or another capture
  // writing it is reported at once; nothing is emptied until the writer starts with the first
  // device (the header describes it). The trace is written in place rather than renamed at the
  // end: a killed application still leaves what was flushed at `path`.
  traces::OutputTarget target;
  const int fd = inheritedFd >= 0 ? traces::adopt_output(inheritedFd, path, &target, &error)
                                  : traces::open_output_in_place(path, &target, &error);
  if (fd < 0) return nullptr;
  return std::make_unique<TraceCaptureSink>(path, fd, zstdLevel, flushMilliseconds, std::move(placement));
}

}  // namespace clastrace::capture
