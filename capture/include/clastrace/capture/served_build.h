// SPDX-License-Identifier: Apache-2.0
// Executing a served vkCmdBuildClusterAccelerationStructureIndirectNV with clastrace's engine,
// and answering vkGetClusterAccelerationStructureBuildSizesNV from the engine's size model.
//
// The layer calls executeServedBuild at the pause before the command, while the queue waits:
// the host bytes of the addressed buffers it reaches become the engine's MemoryImage, the engine runs
// the whole command, and every range its ExecutionRecord marks written is copied back into
// those host bytes. Vulkan specifics (mapping, flush/invalidate) stay with the caller.
#pragma once

#include "clastrace/capture/capture_records.h"

#include <clastrace/engine/execution_record.h>
#include <clastrace/engine/memory_image.h>
#include <clastrace/engine/object_directory.h>
#include <clastrace/engine/properties.h>
#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <memory>
#include <span>
#include <string>
#include <vector>

namespace clastrace::capture {

// One buffer the command may touch, through the host's view of its bytes.
struct ServedBuffer {
    uint64_t buffer = 0;
    VkDeviceAddress address = 0;
    VkDeviceSize size = 0;
    VkBufferUsageFlags usage = 0;
    uint8_t* host = nullptr;  // the first byte of the buffer in host memory
    uint64_t memory = 0;      // the allocation, so the caller can flush what was written
    // Host-cached memory is read with plain loads; other host memory (write-combined on most
    // discrete GPUs) with streaming loads, a line at a time.
    bool cached = true;
    bool coherent = true;  // false: the caller flushes what the build wrote into the allocation
};

// Region bytes that finished served images gave back, for the next images to reuse: a frame
// loop builds from the same buffers every frame, and each fresh page costs a page fault (on
// the H100 most of the page faults of a served run, and the unmapping's TLB shootdowns
// interrupt every thread of the process). Thread-safe; holds at most kMaxBytes.
class ServedRegionPool {
public:
    static constexpr uint64_t kMaxBytes = 256ull << 20;
    // Pauses whose takes make the demand that make_one_ready() meets.
    static constexpr size_t kDemandPauses = 8;
    // Bytes of exactly `size`, or an empty RegionBytes when none is held.
    engine::RegionBytes take(uint64_t size);
    void give(std::vector<engine::RegionBytes> storage);
    uint64_t held_bytes() const;

    // With capture the images of records not yet written hold their regions, and the next
    // pause's copies would fault in fresh pages while the queue waits. The demand is, per size,
    // the most regions one of the last kDemandPauses pauses took; between pauses the worker
    // makes regions ready up to it.
    void pause_ended();  // the takes since the last call were one pause's
    // Adds one region, its pages faulted in, of a size the pool holds fewer of than the demand
    // (within kMaxBytes); false when there is none such or the memory cannot be had.
    bool make_one_ready();

private:
    std::optional<uint64_t> size_short_of_demand() const;  // under mutex_
    mutable std::mutex mutex_;
    std::multimap<uint64_t, engine::RegionBytes> by_size_;
    uint64_t held_ = 0;
    std::map<uint64_t, uint32_t> taken_now_;            // size -> takes this pause
    std::vector<std::map<uint64_t, uint32_t>> recent_;  // the last pauses' takes, oldest first
};

// The served buffers as the engine will see them: buffers whose address ranges overlap
// (aliases) form one group, one region of the image, and a group is copied from host memory
// the first time anything reads it. The capture's walk of the command's inputs and the served
// build then read the application's memory once, through one copy, instead of each on its own
// (reads from uncached memory are what a pause pays for most).
class ServedMemory {
public:
    // `pool`, when given, lends the regions' bytes and gets them back from the images made here.
    explicit ServedMemory(std::vector<ServedBuffer> buffers,
                          std::shared_ptr<ServedRegionPool> pool = nullptr);
    ~ServedMemory();
    ServedMemory(const ServedMemory&) = delete;
    ServedMemory& operator=(const ServedMemory&) = delete;

    // [address, address + size) when one served buffer holds all of it, its group copied into
    // the image first; null otherwise. Valid until the next reset().
    const uint8_t* read(VkDeviceAddress address, uint64_t size);
    // The same bytes as a view that keeps the image alive (its group stays in what share()
    // returns); false when read() would give null. The engine may still write over a view: see
    // keepInputsAsRead.
    bool view(VkDeviceAddress address, uint64_t size, CapturedBytes* out);
    // Views into the image the engine last ran on whose bytes it wrote (`written`: its record;
    // null: it may have written anything) become copies of the application's bytes, which the
    // build has not written back yet: a captured input stays what the command read.
    void keep_inputs_as_read(std::vector<CapturedRange>& inputs,
                             const engine::ExecutionRecord* written) const;

    // For executeServedBuild: the groups, which are in the image, copying and starting over.
    struct Group {
        uint64_t base = 0, end = 0;
        VkBufferUsageFlags usage = 0;
        std::vector<const ServedBuffer*> buffers;
    };
    const std::vector<Group>& groups() const { return groups_; }
    std::span<const ServedBuffer> buffers() const { return buffers_; }  // as given
    size_t group_of(uint64_t address) const;  // groups().size() when no group holds it
    // The buffer holding all of [address, address + size) that starts nearest below it; null
    // when none does.
    const ServedBuffer* buffer_holding(VkDeviceAddress address, uint64_t size) const;
    bool copied(size_t group) const { return copied_[group]; }
    void copy(size_t group);
    // An empty image, as before any read (the engine wrote into the last one); the last image's
    // bytes go back to the pool with its last owner (views of it may live on).
    void reset();
    engine::MemoryImage& image() { return *image_; }
    const engine::MemoryImage& image() const { return *image_; }
    uint64_t bytes_copied() const { return bytes_copied_; }  // since the last reset()
    // The image as it stands, shared; its bytes go back to the pool when the last owner lets go.
    // The regions of groups not in `keep` (when given: one flag per group) and not viewed go back
    // at once. The image here is empty afterwards (as after reset()).
    std::shared_ptr<const engine::MemoryImage> share(const std::vector<bool>* keep = nullptr);
    // Runs on every copy of the application's bytes into the image (or into a captured input)
    // before anything reads them: the traceable mode lays the engine's bytes over the driver's
    // BVHs there (TraceableEngineBytes).
    using HostOverlay = std::function<void(uint64_t address, uint8_t* bytes, uint64_t size)>;
    void set_host_overlay(HostOverlay overlay) { overlay_ = std::move(overlay); }

private:
    // `b`'s bytes [offset, offset + size) into `to`, overlaid.
    void copy_in(const ServedBuffer& b, uint64_t offset, uint64_t size, uint8_t* to) const;

    std::shared_ptr<ServedRegionPool> pool_;
    HostOverlay overlay_;
    std::vector<ServedBuffer> buffers_;  // the groups point into it
    std::vector<Group> groups_;
    std::vector<bool> copied_;
    std::vector<bool> viewed_;  // groups of the image that views (view()) point into
    std::shared_ptr<engine::MemoryImage> image_;
    uint64_t bytes_copied_ = 0;
    const ServedBuffer* last_read_ = nullptr;  // the buffer the last read() found, its group, and
    size_t last_group_ = 0;                    // that group's bytes in the image (null: not known)
    const uint8_t* last_group_bytes_ = nullptr;
};

struct ServedExecution {
    bool ran = false;  // false: the engine could not start (see `error`)
    std::string error;
    engine::ExecutionRecord record;
    std::vector<uint64_t> written_memories;  // allocations that received bytes (to flush)
    uint64_t bytes_copied_in = 0, bytes_written_back = 0;  // of the last attempt
    uint32_t attempts = 0;  // engine runs until the image held every buffer the command reads
    // The image of the last run as it left it; with `outputEntries` given, reduced to what
    // completeServedRecord reads: the groups the command wrote into, those holding its address
    // and size arrays, and those holding the objects these arrays name. The capture reads the
    // command's outputs from it after the queue was released, maybe much later: the input groups
    // (most of the bytes) go back to the region pool at once, for the next pause to reuse.
    std::shared_ptr<const engine::MemoryImage> image;
};

// Only the buffers the command reaches are copied: those it names, those its pointers lead to
// and those already read through `memory`, then those its findings point into, found by running
// again; the result equals a run over all of the buffers. `inputWalk`: the command's inputs as
// the capture already walked them at this pause (saves walking twice; its views into `memory`
// that the build writes over become copies of what it read), or null. `memory` is
// used up: its image becomes the result's. `outputEntries`: the dst array entries a later
// completeServedRecord walks (the record's executedCount), to keep only what it reads; none
// when nothing reads the image afterwards (serving only: the image is kept whole).
// `after_write_back`, when given, runs once the engine's writes are in the host bytes, with the
// whole image of the run and the run's record (the traceable mode builds the driver's BLASes at
// the destinations its ops name).
// `implicit_object_room`: engine::ExecuteOptions::implicit_object_room (traceable BLASes).
using AfterServedWriteBack =
    std::function<void(const engine::MemoryImage& image, const engine::ExecutionRecord& record)>;
ServedExecution execute_served_build(const VkClusterAccelerationStructureCommandsInfoNV& command,
                                     ServedMemory& memory, engine::ObjectDirectory& directory,
                                     const engine::EngineProperties& properties,
                                     std::vector<CapturedRange>* input_walk = nullptr,
                                     std::optional<uint32_t> output_entries = std::nullopt,
                                     const AfterServedWriteBack& after_write_back = {},
                                     uint64_t implicit_object_room = 0);
// The same over a fresh ServedMemory of `buffers`.
ServedExecution execute_served_build(const VkClusterAccelerationStructureCommandsInfoNV& command,
                                     std::span<const ServedBuffer> buffers,
                                     engine::ObjectDirectory& directory,
                                     const engine::EngineProperties& properties,
                                     std::vector<CapturedRange>* input_walk = nullptr);

// The rest of a served build's record, after the queue moved on: its outputs walked in the
// engine's image of the run (as a pause after the command would have read them: the queue ran
// nothing in between) and every range named by the buffer of `memory` holding it (the one
// starting nearest below it), as the buffers were at the pause. Ranges no buffer of `memory`
// holds stay unnamed. The outputs are views into `image`, which they keep alive.
void complete_served_record(ClusterBuildCapture& record,
                            std::shared_ptr<const engine::MemoryImage> image,
                            const ClusterCommandParameters& parameters, const ServedMemory& memory);

// vkGetClusterAccelerationStructureBuildSizesNV of the served device: engine::cluster_build_sizes.
// False (and zero sizes) when the engine rejects the input (its findings say why).
bool served_cluster_build_sizes(const VkClusterAccelerationStructureInputInfoNV& input,
                                VkAccelerationStructureBuildSizesInfoKHR& sizes);

}  // namespace clastrace::capture
