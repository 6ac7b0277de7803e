// SPDX-License-Identifier: Apache-2.0
// Stops the queue at each captured command and reads memory while it waits.
//
// Per captured command the layer records, around it in the application's command buffer:
//
//   vkCmdPipelineBarrier(ALL_COMMANDS -> ALL_COMMANDS|HOST, MEMORY_WRITE -> HOST_READ|MEMORY_READ)
//       every write recorded or submitted before (copies, fills, updates, shaders) is complete,
//       and available and visible to the host, once the event below is observed set;
//   vkCmdSetEvent(signal, ALL_COMMANDS)
//   vkCmdWaitEvents(release, HOST -> ALL_COMMANDS, HOST_WRITE -> MEMORY_READ|MEMORY_WRITE)
//       the queue waits for the worker; what the worker wrote (when serving) is visible to
//       the commands after;
//   vkCmdResetEvent(release, ALL_COMMANDS)  so the command buffer can run again.
//
// The application's own barriers still apply between its commands; the injected ones only add
// the host as an observer. The worker polls `signal` with vkGetEventStatus, resets it from the
// host, reads, and sets `release`. Pauses of one queue are handled in submission order.
#pragma once

#include "clastrace/capture/capture_records.h"
#include "clastrace/capture/cluster_input_walker.h"
#include "clastrace/capture/device_memory_map.h"
#include "clastrace/capture/shared_pause_tracker.h"
#include "clastrace/capture/exact_address_writes.h"
#include "pause_staging.h"
#include "clastrace/capture/served_build.h"

#include <clastrace/engine/memory_image.h>
#include <clastrace/engine/object_directory.h>

#include <chrono>
#include <condition_variable>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <tuple>
#include <vector>
#include <vulkan/vulkan_core.h>

namespace clastrace::capture {

struct DeviceState;

enum class PausePhase { kBeforeCommand, kAfterCommand };

struct PausePoint {
    uint64_t pause_id = 0;
    PausePhase phase = PausePhase::kBeforeCommand;
    bool last_of_command = true;  // the capture of this command is complete after this pause
    // Which execution of this pause within one submission (a simultaneous-use command buffer
    // may run twice in one vkQueueSubmit; its pauses then come twice, in order).
    uint32_t occurrence = 0;
    // Its command buffer may run on two queues at once (a SIMULTANEOUS_USE primary, or a
    // simultaneous-use secondary): submissions wait until no other queue uses its events.
    bool shared = false;
    VkEvent signal = VK_NULL_HANDLE;
    VkEvent release = VK_NULL_HANDLE;
    std::shared_ptr<const ClusterCommandParameters> parameters;  // a cluster build, or one of:
    std::shared_ptr<const BuildAccelerationStructureNVCommand> build_nv;
    std::shared_ptr<const CopyMemoryToAccelerationStructureCommand> copy_to_acceleration_structure;
    // Or a dispatch that may write through device addresses, under
    // CLASTRACE_DEVICE_ADDRESS_WRITES=exact: its two pauses compare memory.
    bool address_writes = false;
    std::shared_ptr<const BuildAccelerationStructuresKHRCommand> build_khr;
    std::shared_ptr<const CopyAccelerationStructureCommand> copy_acceleration_structure;
    std::shared_ptr<const TraceRaysCommand> trace_rays;  // an indirect form
    std::shared_ptr<const StagingSet>
        staging;  // copies of unmapped memory, or null (pause_staging.h)
};

class PauseWorker {
public:
    explicit PauseWorker(DeviceState& device);
    ~PauseWorker();  // stops the thread; pauses not reached are abandoned

    // Called inside the application's vkQueueSubmit, in submission order per queue.
    void expect(VkQueue queue, uint64_t submission_index, bool capture_this_submission,
                uint64_t command_buffer, const std::vector<PausePoint>& pauses);

    // Waits until no queue other than `queue` uses any of the pause events `releases` (see
    // shared_pause_tracker.h); false when `timeout` passed first (the other queue may wait for
    // something the application does only after this submission).
    bool wait_until_free(VkQueue queue, const std::vector<uint64_t>& releases,
                         std::chrono::milliseconds timeout);
    // The command buffer owning these events was reset or freed.
    void forget_events(const std::vector<VkEvent>& events);

    // Total pauses handled and the host time spent inside them, for the report line at exit.
    uint64_t pauses_handled() const { return handled_; }

private:
    struct Expected {
        VkQueue queue;
        PausePoint pause;
        uint64_t submission_index;
        uint64_t command_buffer;
        bool capture;
    };
    // (submission, pauseId, occurrence) of a command's capture between its pauses
    using OpenKey = std::tuple<uint64_t, uint64_t, uint32_t>;
    void run();
    bool handle(Expected& expected);
    // A pause of `address_writes`: copies memory before, compares after (exact_address_writes.h).
    bool handle_address_writes(Expected& expected);
    ClusterBuildCapture* open_record(const Expected& expected, const OpenKey& key,
                                     const DeviceMemoryReader& reader);
    ClusterMemoryWalk walk_command_inputs(const PausePoint& pause, ClusterBuildCapture& record,
                                          const DeviceMemoryReader& reader);
    ClusterBuildCapture* add_outputs_to_open_record(const PausePoint& pause, const OpenKey& key,
                                                    const DeviceMemoryReader& reader);
    void add_outputs(ClusterBuildCapture& record, const ClusterCommandParameters& parameters,
                     const DeviceMemoryReader& reader);
    void learn_pending_templates(const PausePoint& pause);
    std::shared_ptr<const engine::MemoryImage> finish_served_command(
        const PausePoint& pause, ServedMemory& served, ClusterBuildCapture* record,
        const DeviceMemoryReader& reader);
    double release_queue(const Expected& expected, std::chrono::steady_clock::time_point started,
                         uint64_t started_cpu);
    void pass_record_on(const OpenKey& key,
                        std::shared_ptr<const ClusterCommandParameters> parameters,
                        std::shared_ptr<const engine::MemoryImage> served_image,
                        std::unique_ptr<ServedMemory> served);
    void name_ranges(ClusterBuildCapture& record);  // by the memory map, now
    bool check_memory(VkDeviceAddress address, uint64_t size, std::string& why);
    bool read_memory(VkDeviceAddress address, uint64_t size, CapturedBytes& out, std::string& why);
    bool read_resolved(const ResolvedRange& range, uint64_t size, CapturedBytes& out);
    // The host bytes of `range`: the layer's mapping, or the current pause's staged copy; null
    // when neither holds it.
    const uint8_t* staged_bytes(const ResolvedRange& range);
    // Serving: runs the command in the engine against the application's memory and writes its
    // outputs back, while the queue waits at the pause before it.
    // Returns the engine's image of the run (null when it could not run).
    std::shared_ptr<const engine::MemoryImage> execute_served(const PausePoint& pause,
                                                              ServedMemory& memory,
                                                              ClusterBuildCapture* record);
    // The buffers a served build can reach (mapped ones, and the pause's staged copies), their
    // non-coherent memory invalidated.
    std::vector<ServedBuffer> prepare_served_buffers();
    // Between pauses: the served region pool's regions for the next pause's copies.
    void make_regions_ready();
    std::shared_ptr<ServedRegionPool> region_pool_ = std::make_shared<ServedRegionPool>();

    DeviceState& device_;
    std::mutex mutex_;
    std::condition_variable wake_;
    std::map<VkQueue, std::deque<Expected>> queues_;
    std::map<OpenKey, ClusterBuildCapture> open_;
    ExactAddressWrites address_writes_;  // copies taken at the pauses before marked dispatches
    std::vector<float> pause_milliseconds_;
    const StagingSet* staging_ =
        nullptr;  // of the pause being handled  // host time of each pause, for the report at exit
    bool stop_ = false;
    SharedPauseTracker shared_;  // guarded by mutex_
    std::atomic<uint64_t> handled_{0};
    std::map<std::string, uint64_t> findings_per_rule_;  // how often each engine rule was logged
    engine::ObjectDirectory directory_;  // the served device's live objects, across its commands
    // Templates built under the layer: address -> vertex count, so an instantiation's vertex
    // array is captured at its real length. Pending: a template build's counts until its outputs.
    void learn_templates(const ClusterCommandParameters& parameters,
                         const std::vector<uint32_t>& vertex_counts);
    // A move of templates: the vertex count of each source, to be learned at its destination.
    std::vector<uint32_t> moved_template_vertex_counts(const ClusterCommandParameters& parameters,
                                                       uint32_t executed_count);
    std::map<uint64_t, std::vector<uint32_t>>
        pending_template_vertex_counts_;  // pauseId -> per entry
    std::map<VkDeviceAddress, uint32_t> template_vertex_counts_;
    std::thread thread_;
};

}  // namespace clastrace::capture
