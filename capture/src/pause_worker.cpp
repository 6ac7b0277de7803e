#include "pause_worker.h"

#include "clastrace/capture/cluster_input_walker.h"
#include "layer_state.h"

#include <algorithm>
#include <chrono>
#include <cstring>
#include <pthread.h>

#include "clastrace/capture/acceleration_structure_walker.h"
#include "clastrace/capture/capture_cost.h"
#include "clastrace/capture/cluster_limits.h"
#include "clastrace/capture/served_build.h"
#include "clastrace/capture/uncached_copy.h"

namespace clastrace::capture {

namespace {
// About a microsecond of busy waiting that leaves the core's other hyperthread its share.
void spinBriefly() {
  for (int i = 0; i < 32; ++i) {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#elif defined(__aarch64__)
    asm volatile("yield");
#endif
  }
}

const char* const kNotStaged =
    "the memory is not host visible and the buffer has no acceleration-structure usage (build input or storage), "
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
  if (pauseMilliseconds_.empty()) return;
  std::vector<float> sorted = pauseMilliseconds_;
  std::sort(sorted.begin(), sorted.end());
  auto at = [&](double q) { return sorted[std::min(sorted.size() - 1, size_t(q * double(sorted.size())))]; };
  // With CLASTRACE_STATS at any log level: the overhead bench reads it without info logging,
  // which writes a line per served build.
  logMessage(layerConfig().stats ? LogLevel::Quiet : LogLevel::Info,
             "pauses: %zu handled; host time per pause: median %.3f ms, p90 %.3f ms, max %.3f ms", sorted.size(),
             at(0.5), at(0.9), sorted.back());
}

void PauseWorker::expect(VkQueue queue, uint64_t submissionIndex, bool captureThisSubmission, uint64_t commandBuffer,
                         const std::vector<PausePoint>& pauses) {
  if (pauses.empty()) return;
  {
    std::lock_guard lock(mutex_);
    auto& pending = queues_[queue];
    for (const PausePoint& p : pauses) {
      pending.push_back({queue, p, submissionIndex, commandBuffer, captureThisSubmission});
      if (p.shared) shared_.expected(handleId(queue), handleId(p.release));
    }
  }
  wake_.notify_all();
}

bool PauseWorker::waitUntilFree(VkQueue queue, const std::vector<uint64_t>& releases, std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  auto isReset = [this](uint64_t release) {
    return device_.next.GetEventStatus(device_.device, (VkEvent)release) == VK_EVENT_RESET;
  };
  std::unique_lock lock(mutex_);
  while (shared_.busyElsewhere(handleId(queue), releases, isReset)) {
    if (std::chrono::steady_clock::now() >= deadline) return false;
    lock.unlock();
    std::this_thread::sleep_for(std::chrono::microseconds(100));
    lock.lock();
  }
  return true;
}

void PauseWorker::forgetEvents(const std::vector<VkEvent>& events) {
  std::lock_guard lock(mutex_);
  if (shared_.empty()) return;
  for (VkEvent e : events) shared_.forget(handleId(e));
}

void PauseWorker::run() {
  markLayerThread();
  pthread_setname_np(pthread_self(), "clastrace-pause");  // for profilers and top
  struct CpuAtExit {  // the worker's CPU time, for CLASTRACE_STATS
    ~CpuAtExit() { addThreadCpu(CostThread::PauseWorker, threadCpuNs()); }
  } cpuAtExit;
  using Clock = std::chrono::steady_clock;
  auto lastProgress = Clock::now();
  std::unique_lock lock(mutex_);
  while (!stop_) {
    bool anyPending = false;
    bool progressed = false;
    for (auto& [queue, pending] : queues_) {
      if (pending.empty()) continue;
      anyPending = true;
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
    if (!anyPending) {
      if (device_.sink) {  // idle: free the written records' bytes here, where they were allocated
        lock.unlock();
        device_.sink->releaseWritten();
        lock.lock();
      }
      wake_.wait(lock, [this] { return stop_ || std::any_of(queues_.begin(), queues_.end(),
                                                              [](auto& q) { return !q.second.empty(); }); });
      lastProgress = Clock::now();
      continue;
    }
    if (progressed) {
      lastProgress = Clock::now();
      continue;
    }
    // A queue is about to reach a pause or is still far from it: spin briefly (the queue is
    // stalled while we sleep), then back off so an idle wait does not burn a core. The spin
    // does not yield: a yield can hand the core to the sink's and compressor's background
    // threads until the next scheduler tick, while the queue may already wait.
    lock.unlock();
    if (Clock::now() - lastProgress < std::chrono::microseconds(2000))
      spinBriefly();
    else
      std::this_thread::sleep_for(std::chrono::microseconds(50));
    lock.lock();
  }
}

const uint8_t* PauseWorker::stagedBytes(const ResolvedRange& range) {
  if (range.host) return range.host;
  const StagedBuffer* staged = staging_ ? staging_->find(range.buffer.handle) : nullptr;
  if (!staged) return nullptr;
  if (!staging_->coherent) {  // the queue's copy reaches the host view only after an invalidate
    VkMappedMemoryRange whole{VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE, nullptr, staging_->memory, 0, VK_WHOLE_SIZE};
    device_.next.InvalidateMappedMemoryRanges(device_.device, 1, &whole);
  }
  return staging_->host + staged->offset + range.offsetInBuffer;
}

bool PauseWorker::checkMemory(VkDeviceAddress address, uint64_t size, std::string& why) {
  auto range = device_.memoryMap.resolve(address, size, why);
  if (!range) return false;
  if (!range->host && !(staging_ && staging_->find(range->buffer.handle))) {
    why = kNotStaged;
    return false;
  }
  return true;
}

bool PauseWorker::readResolved(const ResolvedRange& range, uint64_t size, CapturedBytes& out) {
  if (!range.host) {
    const uint8_t* staged = stagedBytes(range);
    if (!staged) return false;
    uint8_t* to = out.fill(size);
    if (staging_->cached) std::memcpy(to, staged, size);
    else copyFromUncached(to, staged, size);
    return true;
  }
  if (!(range.memory.propertyFlags & VK_MEMORY_PROPERTY_HOST_COHERENT_BIT)) {
    // Device writes to non-coherent memory reach the host view only after an invalidate of
    // whole atoms.
    const VkDeviceSize atom = device_.nonCoherentAtomSize;
    const VkDeviceSize first = range.buffer.memoryOffset + range.offsetInBuffer;
    const VkDeviceSize begin = first / atom * atom;
    const VkDeviceSize end = (first + size + atom - 1) / atom * atom;
    VkMappedMemoryRange mapped{VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE, nullptr, (VkDeviceMemory)range.memory.handle,
                               begin, end >= range.memory.size ? VK_WHOLE_SIZE : end - begin};
    device_.next.InvalidateMappedMemoryRanges(device_.device, 1, &mapped);
  }
  uint8_t* to = out.fill(size);
  if (range.memory.propertyFlags & VK_MEMORY_PROPERTY_HOST_CACHED_BIT) {
    if (size) std::memcpy(to, range.host, size);
  } else {
    copyFromUncached(to, range.host, size);
  }
  return true;
}

bool PauseWorker::readMemory(VkDeviceAddress address, uint64_t size, CapturedBytes& out, std::string& why) {
  auto range = device_.memoryMap.resolve(address, size, why);
  if (!range) return false;
  if (!readResolved(*range, size, out)) {
    why = kNotStaged;
    return false;
  }
  return true;
}

bool PauseWorker::handle(Expected& expected) {
  const PausePoint& pause = expected.pause;
  if (device_.next.GetEventStatus(device_.device, pause.signal) != VK_EVENT_SET) return false;
  const auto started = std::chrono::steady_clock::now();
  const uint64_t startedCpu = threadCpuNs();
  staging_ = pause.staging.get();
  const bool capture = expected.capture && device_.capturingNow();
  // A served build reads the application's memory through the engine's image; the capture's
  // walk reads through the same copy, so each byte crosses from (often uncached) memory once,
  // and its ranges are views into that copy rather than copies of their own.
  std::unique_ptr<ServedMemory> served;
  if (device_.serving && pause.phase == PausePhase::BeforeCommand && pause.parameters)
    served = std::make_unique<ServedMemory>(prepareServedBuffers(), regionPool_);
  DeviceMemoryReader reader = [this, &served](VkDeviceAddress a, uint64_t s, CapturedBytes* o, std::string& w) {
    if (served && served->view(a, s, o)) return true;  // (executeServedBuild keeps them what was read)
    if (!o) return checkMemory(a, s, w);
    return readMemory(a, s, *o, w);
  };

  ClusterBuildCapture* record = nullptr;
  const OpenKey openKey = std::make_tuple(expected.submissionIndex, pause.pauseId, pause.occurrence);
  if (capture) {
    CostScope cost(CostPhase::PauseRead);
    if (pause.phase == PausePhase::BeforeCommand) record = openRecord(expected, openKey, reader);
    else record = addOutputsToOpenRecord(pause, openKey, reader);
  }
  std::shared_ptr<const engine::MemoryImage> servedImage;
  if (served) servedImage = finishServedCommand(pause, *served, record, reader);
  const double stalled = releaseQueue(expected, started, startedCpu);
  staging_ = nullptr;  // the queue may overwrite the staged copies from here on
  if (!record) return true;
  record->pauseMilliseconds += stalled;
  if (!pause.lastOfCommand) {  // the record waits in open_ for the command's next pause
    nameRanges(*record);
    return true;
  }
  passRecordOn(openKey, pause.parameters, std::move(servedImage), std::move(served));
  return true;
}

// Opens the capture of a command at its pause before it, with the inputs the command reads.
ClusterBuildCapture* PauseWorker::openRecord(const Expected& expected, const OpenKey& key,
                                             const DeviceMemoryReader& reader) {
  const PausePoint& pause = expected.pause;
  ClusterBuildCapture fresh;
  fresh.pauseId = pause.pauseId;
  fresh.occurrence = pause.occurrence;
  fresh.submissionIndex = expected.submissionIndex;
  fresh.commandBuffer = expected.commandBuffer;
  ClusterMemoryWalk walk = walkCommandInputs(pause, fresh, reader);
  ClusterBuildCapture* record = &open_.insert_or_assign(key, std::move(fresh)).first->second;
  record->executedCount = walk.executedCount;
  record->inputs = std::move(walk.ranges);
  record->issues = std::move(walk.issues);
  return record;
}

// Walks the inputs of the pause's command, by its kind; sets `record`'s kind and parameters.
ClusterMemoryWalk PauseWorker::walkCommandInputs(const PausePoint& pause, ClusterBuildCapture& record,
                                                 const DeviceMemoryReader& reader) {
  if (pause.buildNV) {
    record.kind = CapturedCommandKind::BuildAccelerationStructureNV;
    BufferMemoryReader bufferReader = [this](uint64_t buffer, VkDeviceSize offset, uint64_t size,
                                             CapturedBytes* out, std::string& why) {
      auto range = device_.memoryMap.resolveBuffer(buffer, offset, size, why);
      if (!range) return false;
      if (!range->host && !(staging_ && staging_->find(range->buffer.handle))) {
        why = kNotStaged;
        return false;
      }
      return out ? readResolved(*range, size, *out) : true;
    };
    ClusterMemoryWalk walk = walkBuildAccelerationStructureNVInputs(*pause.buildNV, bufferReader);
    device_.nvScene.observeBuild(*pause.buildNV, walk.ranges);  // for the ray check
    return walk;
  }
  if (pause.copyToAccelerationStructure) {
    record.kind = CapturedCommandKind::CopyMemoryToAccelerationStructure;
    return walkCopyMemoryToAccelerationStructureInputs(*pause.copyToAccelerationStructure, reader);
  }
  record.parameters = *pause.parameters;
  ClusterMemoryWalk walk =
      walkClusterInputs(*pause.parameters, reader, [this](VkDeviceAddress address, uint32_t* vertices) {
        auto it = templateVertexCounts_.find(address);
        if (it == templateVertexCounts_.end()) return false;
        *vertices = it->second;
        return true;
      });
  if (!walk.templateVertexCounts.empty())
    pendingTemplateVertexCounts_[pause.pauseId] = std::move(walk.templateVertexCounts);
  else if (pause.parameters->info.input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV &&
           pause.parameters->moveObjectsInput.type == VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_TEMPLATE_NV)
    pendingTemplateVertexCounts_[pause.pauseId] = movedTemplateVertexCounts(*pause.parameters, walk.executedCount);
  return walk;
}

// At the pause after a cluster command: its outputs join the record its first pause opened
// (null when there is none).
ClusterBuildCapture* PauseWorker::addOutputsToOpenRecord(const PausePoint& pause, const OpenKey& key,
                                                         const DeviceMemoryReader& reader) {
  auto it = open_.find(key);
  if (it == open_.end() || !pause.parameters) return nullptr;
  ClusterBuildCapture* record = &it->second;
  addOutputs(*record, *pause.parameters, reader);
  learnPendingTemplates(pause);
  return record;
}

void PauseWorker::addOutputs(ClusterBuildCapture& record, const ClusterCommandParameters& parameters,
                             const DeviceMemoryReader& reader) {
  ClusterMemoryWalk walk = walkClusterOutputs(parameters, record.executedCount, reader);
  record.outputs = std::move(walk.ranges);
  for (auto& issue : walk.issues) record.issues.push_back(std::move(issue));
}

// The templates the pause's command built (or moved), once its dstAddressesArray is written.
void PauseWorker::learnPendingTemplates(const PausePoint& pause) {
  auto pending = pendingTemplateVertexCounts_.find(pause.pauseId);
  if (pending == pendingTemplateVertexCounts_.end()) return;
  learnTemplates(*pause.parameters, pending->second);
  pendingTemplateVertexCounts_.erase(pending);
}

// Served, the command has executed once the engine returns, and its outputs are what a pause
// after it would read (the queue runs nothing in between). The engine's image holds them (and
// everything the command read), so they are walked there after the queue is released; if
// the engine could not run, from memory now.
std::shared_ptr<const engine::MemoryImage> PauseWorker::finishServedCommand(const PausePoint& pause,
                                                                            ServedMemory& served,
                                                                            ClusterBuildCapture* record,
                                                                            const DeviceMemoryReader& reader) {
  std::shared_ptr<const engine::MemoryImage> servedImage;
  {
    CostScope cost(CostPhase::PauseEngine);
    servedImage = executeServed(pause, served, record);
  }
  // No pause follows a served command: learn the templates it built (or moved) now, while
  // its dstAddressesArray holds what the engine just wrote and the queue still waits.
  if (pause.lastOfCommand) learnPendingTemplates(pause);
  if (record && pause.lastOfCommand && !servedImage) addOutputs(*record, *pause.parameters, reader);
  return servedImage;
}

// Lets the queue run on past the pause; returns how long it was held, in milliseconds.
double PauseWorker::releaseQueue(const Expected& expected, std::chrono::steady_clock::time_point started,
                                 uint64_t startedCpu) {
  const PausePoint& pause = expected.pause;
  device_.next.ResetEvent(device_.device, pause.signal);
  device_.next.SetEvent(device_.device, pause.release);
  if (pause.shared) {
    std::lock_guard lock(mutex_);
    shared_.released(handleId(expected.queue), handleId(pause.release));
  }
  ++handled_;
  const auto released = std::chrono::steady_clock::now();
  const uint64_t releasedCpu = threadCpuNs();
  const double stalled = std::chrono::duration<double, std::milli>(released - started).count();
  pauseMilliseconds_.push_back(float(stalled));
  addCost(CostPhase::PauseHeld, uint64_t(stalled * 1e6), releasedCpu - startedCpu);
  return stalled;
}

// Hands the finished record of the command to the sink.
// A served record leaves unfinished: the sink's thread walks its outputs in the engine's
// image and names its ranges by this pause's buffers (the application may destroy them once
// the queue moved on), while this thread takes the next pause. Any other record is named now,
// by the memory map, before the queue passes its last pause and the application may destroy
// the buffers that name the ranges.
void PauseWorker::passRecordOn(const OpenKey& key, std::shared_ptr<const ClusterCommandParameters> parameters,
                               std::shared_ptr<const engine::MemoryImage> servedImage,
                               std::unique_ptr<ServedMemory> served) {
  auto it = open_.find(key);
  ClusterBuildCapture work = std::move(it->second);
  open_.erase(it);
  if (servedImage) {  // (set only when the build was served and ran)
    work.heldBytes = servedImage->resident_bytes();
    work.complete = [image = std::move(servedImage), parameters = std::move(parameters),
                     memory = std::shared_ptr<const ServedMemory>(std::move(served))](ClusterBuildCapture& r) {
      completeServedRecord(r, image, *parameters, *memory);
    };
  } else {
    nameRanges(work);
  }
  device_.sink->clusterBuildCaptured(std::move(work));
}

// By a buffer holding each, as the trace's snapshots do: the memory map now.
void PauseWorker::nameRanges(ClusterBuildCapture& record) {
  for (auto* list : {&record.inputs, &record.outputs})
    for (CapturedRange& r : *list) {
      std::string why;
      if (r.address == 0) continue;  // named by buffer and offset already
      if (auto where = device_.memoryMap.resolve(r.address, r.bytes.size(), why)) {
        r.buffer = where->buffer.handle;
        r.bufferOffset = where->offsetInBuffer;
      }
    }
}

void PauseWorker::learnTemplates(const ClusterCommandParameters& parameters, const std::vector<uint32_t>& vertexCounts) {
  const auto& info = parameters.info;
  if (info.input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV ||
      (info.addressResolutionFlags & VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV))
    return;
  const uint64_t stride = info.dstAddressesArray.stride ? info.dstAddressesArray.stride : 8;
  for (size_t i = 0; i < vertexCounts.size(); ++i) {
    CapturedBytes bytes;
    std::string why;
    if (!readMemory(info.dstAddressesArray.deviceAddress + i * stride, 8, bytes, why)) return;
    uint64_t address;
    std::memcpy(&address, bytes.data(), 8);
    if (address != 0 && vertexCounts[i] != 0) templateVertexCounts_[address] = vertexCounts[i];
  }
}

std::vector<uint32_t> PauseWorker::movedTemplateVertexCounts(const ClusterCommandParameters& parameters,
                                                             uint32_t executedCount) {
  std::vector<uint32_t> counts;
  const auto& info = parameters.info;
  if (info.addressResolutionFlags & VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV)
    return counts;
  const uint64_t stride = info.srcInfosArray.stride ? info.srcInfosArray.stride : 8;
  for (uint32_t i = 0; i < executedCount; ++i) {
    CapturedBytes bytes;
    std::string why;
    if (!readMemory(info.srcInfosArray.deviceAddress + i * stride, 8, bytes, why)) break;
    uint64_t source;  // VkClusterAccelerationStructureMoveObjectsInfoNV::srcAccelerationStructure
    std::memcpy(&source, bytes.data(), 8);
    auto it = templateVertexCounts_.find(source);
    counts.push_back(it == templateVertexCounts_.end() ? 0 : it->second);  // 0: unknown, not learned
  }
  return counts;
}

std::vector<ServedBuffer> PauseWorker::prepareServedBuffers() {
  std::vector<ResolvedRange> held = device_.memoryMap.hostAddressedBuffers();
  std::vector<ServedBuffer> buffers;
  buffers.reserve(held.size());
  for (const ResolvedRange& r : held)
    buffers.push_back({r.buffer.handle, r.buffer.address, r.buffer.size, r.buffer.usage, r.host, r.memory.handle,
                       (r.memory.propertyFlags & VK_MEMORY_PROPERTY_HOST_CACHED_BIT) != 0,
                       (r.memory.propertyFlags & VK_MEMORY_PROPERTY_HOST_COHERENT_BIT) != 0});
  // Unmapped buffers take part through their staged copies; the queue copies them back.
  if (staging_)
    for (const StagedBuffer& b : staging_->buffers)
      buffers.push_back({b.buffer.handle, b.buffer.address, b.buffer.size, b.buffer.usage, staging_->host + b.offset,
                         handleId(staging_->memory), staging_->cached, staging_->coherent});
  // What the device wrote to non-coherent memory reaches the host view only after an invalidate.
  std::vector<uint64_t> invalidated;
  for (const ServedBuffer& b : buffers) {
    if (b.coherent || std::find(invalidated.begin(), invalidated.end(), b.memory) != invalidated.end()) continue;
    invalidated.push_back(b.memory);
    VkMappedMemoryRange range{VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE, nullptr, (VkDeviceMemory)b.memory, 0,
                              VK_WHOLE_SIZE};
    device_.next.InvalidateMappedMemoryRanges(device_.device, 1, &range);
  }
  return buffers;
}

std::shared_ptr<const engine::MemoryImage> PauseWorker::executeServed(const PausePoint& pause, ServedMemory& memory,
                                                                      ClusterBuildCapture* record) {
  ServedExecution served =
      executeServedBuild(pause.parameters->resolved(), memory, directory_, servedEngineProperties(),
                         record ? &record->inputs : nullptr,
                         record ? std::optional<uint32_t>(record->executedCount) : std::nullopt);
  if (!served.ran) {
    logMessage(LogLevel::Error, "served build (pause %llu) could not run in the engine: %s",
               (unsigned long long)pause.pauseId, served.error.c_str());
    if (record) record->engineFindings.push_back({"CLASTRACE-engine-could-not-run", served.error, -1, 0});
    return nullptr;
  }
  const std::span<const ServedBuffer> buffers = memory.buffers();
  for (uint64_t written : served.writtenMemories)
    if (std::any_of(buffers.begin(), buffers.end(),
                    [&](const ServedBuffer& b) { return b.memory == written && !b.coherent; })) {
      VkMappedMemoryRange range{VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE, nullptr, (VkDeviceMemory)written, 0,
                                VK_WHOLE_SIZE};
      device_.next.FlushMappedMemoryRanges(device_.device, 1, &range);
    }
  logMessage(LogLevel::Info,
             "served build (pause %llu): %u ops executed by the engine, %zu findings, %llu bytes read in "
             "(%u runs), %llu bytes written",
             (unsigned long long)pause.pauseId, served.record.op_count, served.record.findings.size(),
             (unsigned long long)served.bytesCopiedIn, served.attempts, (unsigned long long)served.bytesWrittenBack);
  // An application repeating one mistake every frame would bury everything else: each rule is
  // logged a few times per device, then once more to say the rest are counted, not printed.
  constexpr uint64_t kLoggedPerRule = 8;
  for (const engine::Finding& f : served.record.findings) {
    const uint64_t seen = ++findingsPerRule_[f.rule];
    if (seen <= kLoggedPerRule)
      logMessage(LogLevel::Error, "served build (pause %llu) op %lld: %s: %s", (unsigned long long)pause.pauseId,
                 (long long)f.op_index, f.rule.c_str(), f.message.c_str());
    if (seen == kLoggedPerRule)
      logMessage(LogLevel::Error, "%s: further findings of this rule on this device are not logged (a capture keeps "
                 "them all)", f.rule.c_str());
  }
  if (record) {
    record->executedByEngine = true;
    for (const engine::Finding& f : served.record.findings)
      record->engineFindings.push_back({f.rule, f.message, f.op_index, f.address});
  }
  return served.image;
}

}  // namespace clastrace::capture
