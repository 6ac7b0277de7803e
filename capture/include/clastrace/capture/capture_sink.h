// Where the layer sends what it captured: one call per record kind. Calls may come from the
// application's threads and from the layer's pause worker; implementations serialize them.
#pragma once

#include "clastrace/capture/capture_records.h"

#include <memory>
#include <string>
#include <vector>

namespace clastrace::capture {

class CaptureSink {
 public:
  virtual ~CaptureSink() = default;
  virtual void deviceCreated(const DeviceRecord&) = 0;
  virtual void deviceDestroyed(uint64_t device) = 0;
  virtual void memoryAllocated(const MemoryRecord&) = 0;
  virtual void memoryFreed(uint64_t memory) = 0;
  virtual void bufferCreated(const BufferRecord&) = 0;
  virtual void bufferBound(const BufferBindingRecord&) = 0;
  virtual void bufferAddressQueried(const BufferAddressRecord&) = 0;
  virtual void bufferDestroyed(uint64_t buffer) = 0;
  virtual void buildSizesQueried(const BuildSizesQuery&) = 0;
  virtual void commandBufferRecorded(const RecordedCommandBuffer&) = 0;
  virtual void commandBufferReset(uint64_t commandBuffer) = 0;
  virtual void queueSubmitted(const SubmissionRecord&) = 0;
  virtual void clusterBuildCaptured(ClusterBuildCapture) = 0;  // by value: the worker moves it in
  virtual void hostSynchronized(const HostSyncRecord&) = 0;
  // False once the sink stopped writing (its one message printed): the layer then saves the
  // work of capturing, and the application runs on as with capture off.
  virtual bool active() const { return true; }
  // Acceleration-structure objects and the ray check (no-ops unless a sink records them).
  virtual void accelerationStructureCreated(const AccelerationStructureRecord&) {}
  virtual void accelerationStructureBound(const AccelerationStructureBindingRecord&) {}
  virtual void accelerationStructureAddressQueried(const AccelerationStructureAddressRecord&) {}
  virtual void accelerationStructureMemoryRequirements(const AccelerationStructureMemoryRequirementsRecord&) {}
  virtual void accelerationStructureDestroyed(uint64_t) {}
  virtual void rayQueryChecked(const RayCheckRecord&) {}
  // vkQueuePresentKHR, recorded whatever the frame range selects (frame boundaries).
  virtual void queuePresented(const PresentRecord&) {}
  // vkAcquireNextImage[2]KHR, recorded like presents (in call order, whatever the range).
  virtual void imageAcquired(const AcquireRecord&) {}
  // Frees the captured bytes of records already written, on the calling thread. The pause
  // worker calls it when idle: the bytes were allocated on its thread, and freeing them there
  // spares the sink's thread the allocator's cross-thread path (and the worker's allocations
  // inside the next pause the contention on its arena's lock).
  virtual void releaseWritten() {}
  // Makes everything received so far durable (the application may exit without cleanup).
  virtual void flush() = 0;
  // Lines for the CLASTRACE_STATS report: what the sink wrote and where its time went.
  virtual std::vector<std::string> costLines() { return {}; }
};

// A human-readable dump of every record (JSON, rewritten on each flush): the test suites read
// it, and it helps debugging a capture before a trace reader exists. False + `error` when the
// path cannot be written.
std::unique_ptr<CaptureSink> makeJsonCaptureSink(const std::string& path, std::string& error);

// The .clt trace the replay reads (CLASTRACE_OUTPUT). Null + `error` when the path cannot be
// written, or while this build has no trace writer.
// Every `flushMilliseconds` (0: never) the records so far are written out as a finished chunk,
// so a process that is killed loses at most that much of its capture.
// Its two threads (the sink's and the compressor's) run on `placement.cpus` when not empty
// (background_cpus.h); `applicationCpus` is only reported.
struct BackgroundPlacement {
  std::vector<unsigned> cpus;
  std::vector<unsigned> applicationCpus;
};
// The output follows traces/output_file.h's rule and is written in place: it is opened (or,
// with `inheritedFd` >= 0, taken over from `clastrace capture`) and locked here, and emptied
// only when the first device starts the trace. Another process holding the lock (another
// capture of the same path) makes this fail with `error` saying so.
std::unique_ptr<CaptureSink> makeTraceCaptureSink(const std::string& path, int zstdLevel, std::string& error,
                                                  uint32_t flushMilliseconds = 1000,
                                                  BackgroundPlacement placement = {}, int inheritedFd = -1);

}  // namespace clastrace::capture
