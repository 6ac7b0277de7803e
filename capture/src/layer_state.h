// SPDX-License-Identifier: Apache-2.0
// The layer's per-instance and per-device state, found by the loader's dispatch key (the first
// pointer-sized word of every dispatchable handle), and the next layer's entry points.
#pragma once

#include "clastrace/capture/capture_sink.h"
#include "clastrace/capture/device_memory_map.h"
#include "consumer_descriptor_buffers.h"
#include "host_write_watch.h"
#include "clastrace/capture/layer_config.h"
#include "clastrace/capture/nv_scene_model.h"

#include <clastrace/vk_cluster_abi.h>
#include <clastrace/vk_frame_boundary_abi.h>
#include <clastrace/vk_maintenance6_abi.h>
#include <vulkan/vk_layer.h>

#include <atomic>
#include <cstdarg>
#include <functional>
#include <memory>
#include <mutex>
#include <shared_mutex>
#include <map>
#include <unordered_map>
#include <unordered_set>
#include <variant>
#include <vector>

namespace clastrace::engine {
class MemoryImage;
struct OpResult;
}  // namespace clastrace::engine

namespace clastrace::capture {

class PauseWorker;
class TraceableDriver;
class ServedMemory;
struct CommandBufferLog;

using DispatchKey = void*;
template <typename Handle>
DispatchKey dispatch_key(Handle handle) {
    return *reinterpret_cast<DispatchKey*>(handle);
}
template <typename Handle>
uint64_t handle_id(Handle handle) {
    return (uint64_t)(handle);
}

#define CLASTRACE_INSTANCE_FUNCTIONS(X)       \
    X(GetInstanceProcAddr)                    \
    X(DestroyInstance)                        \
    X(EnumerateDeviceExtensionProperties)     \
    X(GetPhysicalDeviceFeatures2)             \
    X(GetPhysicalDeviceFeatures2KHR)          \
    X(GetPhysicalDeviceProperties)            \
    X(GetPhysicalDeviceProperties2)           \
    X(GetPhysicalDeviceProperties2KHR)        \
    X(GetPhysicalDeviceMemoryProperties)      \
    X(GetPhysicalDeviceQueueFamilyProperties) \
    X(CreateDevice)

#define CLASTRACE_DEVICE_FUNCTIONS(X)                 \
    X(GetDeviceProcAddr)                              \
    X(DestroyDevice)                                  \
    X(AllocateMemory)                                 \
    X(FreeMemory)                                     \
    X(MapMemory)                                      \
    X(UnmapMemory)                                    \
    X(InvalidateMappedMemoryRanges)                   \
    X(FlushMappedMemoryRanges)                        \
    X(CreateBuffer)                                   \
    X(DestroyBuffer)                                  \
    X(BindBufferMemory)                               \
    X(GetBufferMemoryRequirements)                    \
    X(BindBufferMemory2)                              \
    X(BindBufferMemory2KHR)                           \
    X(GetBufferDeviceAddress)                         \
    X(GetBufferDeviceAddressKHR)                      \
    X(GetBufferDeviceAddressEXT)                      \
    X(CreateEvent)                                    \
    X(DestroyEvent)                                   \
    X(GetEventStatus)                                 \
    X(SetEvent)                                       \
    X(ResetEvent)                                     \
    X(AllocateCommandBuffers)                         \
    X(FreeCommandBuffers)                             \
    X(ResetCommandPool)                               \
    X(DestroyCommandPool)                             \
    X(BeginCommandBuffer)                             \
    X(EndCommandBuffer)                               \
    X(ResetCommandBuffer)                             \
    X(CmdPipelineBarrier)                             \
    X(CmdPipelineBarrier2)                            \
    X(CmdPipelineBarrier2KHR)                         \
    X(CmdSetEvent)                                    \
    X(CmdSetEvent2)                                   \
    X(CmdSetEvent2KHR)                                \
    X(CmdResetEvent)                                  \
    X(CmdResetEvent2)                                 \
    X(CmdResetEvent2KHR)                              \
    X(CmdWaitEvents)                                  \
    X(CmdWaitEvents2)                                 \
    X(CmdWaitEvents2KHR)                              \
    X(CmdCopyBuffer)                                  \
    X(CmdCopyBuffer2)                                 \
    X(CmdCopyBuffer2KHR)                              \
    X(CmdFillBuffer)                                  \
    X(CmdUpdateBuffer)                                \
    X(CmdDispatch)                                    \
    X(CmdDispatchIndirect)                            \
    X(CreateShaderModule)                             \
    X(DestroyShaderModule)                            \
    X(CreateComputePipelines)                         \
    X(CreateGraphicsPipelines)                        \
    X(CmdDraw)                                        \
    X(CmdDrawIndexed)                                 \
    X(CmdDrawIndirect)                                \
    X(CmdDrawIndexedIndirect)                         \
    X(CmdDrawIndirectCount)                           \
    X(CmdDrawIndexedIndirectCount)                    \
    X(CmdDrawMeshTasksEXT)                            \
    X(CmdDrawMeshTasksIndirectEXT)                    \
    X(CmdDrawMeshTasksIndirectCountEXT)               \
    X(CmdDrawMeshTasksNV)                             \
    X(CmdDrawMeshTasksIndirectNV)                     \
    X(CmdDrawMeshTasksIndirectCountNV)                \
    X(DestroyPipeline)                                \
    X(CmdBindPipeline)                                \
    X(CmdBindDescriptorSets)                          \
    X(UpdateDescriptorSets)                           \
    X(CmdExecuteCommands)                             \
    X(CmdBuildClusterAccelerationStructureIndirectNV) \
    X(GetClusterAccelerationStructureBuildSizesNV)    \
    X(CmdBuildAccelerationStructureNV)                \
    X(CmdCopyMemoryToAccelerationStructureKHR)        \
    X(QueueSubmit)                                    \
    X(QueueSubmit2)                                   \
    X(QueueSubmit2KHR)                                \
    X(GetDeviceQueue)                                 \
    X(GetDeviceQueue2)                                \
    X(CreateAccelerationStructureNV)                  \
    X(DestroyAccelerationStructureNV)                 \
    X(BindAccelerationStructureMemoryNV)              \
    X(GetAccelerationStructureHandleNV)               \
    X(GetAccelerationStructureMemoryRequirementsNV)   \
    X(CreateAccelerationStructureKHR)                 \
    X(DestroyAccelerationStructureKHR)                \
    X(GetAccelerationStructureDeviceAddressKHR)       \
    X(WaitForFences)                                  \
    X(ResetFences)                                    \
    X(GetFenceStatus)                                 \
    X(QueueWaitIdle)                                  \
    X(DeviceWaitIdle)                                 \
    X(SignalSemaphore)                                \
    X(SignalSemaphoreKHR)                             \
    X(WaitSemaphores)                                 \
    X(CreateQueryPool)                                \
    X(DestroyQueryPool)                               \
    X(CmdResetQueryPool)                              \
    X(CmdWriteTimestamp)                              \
    X(GetQueryPoolResults)                            \
    X(WaitSemaphoresKHR)                              \
    X(QueuePresentKHR)                                \
    X(AcquireNextImageKHR)                            \
    X(AcquireNextImage2KHR)                           \
    X(QueueBindSparse)                                \
    X(CmdBuildAccelerationStructuresKHR)              \
    X(CmdBuildAccelerationStructuresIndirectKHR)      \
    X(CmdCopyAccelerationStructureKHR)                \
    X(CmdCopyAccelerationStructureNV)                 \
    X(CmdCopyAccelerationStructureToMemoryKHR)        \
    X(CmdWriteAccelerationStructuresPropertiesKHR)    \
    X(CmdWriteAccelerationStructuresPropertiesNV)     \
    X(GetAccelerationStructureBuildSizesKHR)          \
    X(CmdTraceRaysKHR)                                \
    X(CmdTraceRaysIndirectKHR)                        \
    X(CmdTraceRaysIndirect2KHR)                       \
    X(CmdTraceRaysNV)                                 \
    X(CreateRayTracingPipelinesKHR)                   \
    X(CreateRayTracingPipelinesNV)                    \
    X(CmdPushConstants)                               \
    X(CmdPushDescriptorSetKHR)                        \
    X(CmdPushDescriptorSetWithTemplateKHR)            \
    X(CmdBindDescriptorSets2KHR)                      \
    X(CmdPushConstants2KHR)                           \
    X(CmdPushDescriptorSet2KHR)                       \
    X(CmdPushDescriptorSetWithTemplate2KHR)           \
    X(CreateDescriptorSetLayout)                      \
    X(CreatePipelineLayout)                           \
    X(GetDescriptorSetLayoutBindingOffsetEXT)         \
    X(GetDescriptorEXT)                               \
    X(CmdBindDescriptorBuffersEXT)                    \
    X(CmdSetDescriptorBufferOffsetsEXT)               \
    X(CreateDescriptorUpdateTemplate)                 \
    X(CreateDescriptorUpdateTemplateKHR)              \
    X(DestroyDescriptorUpdateTemplate)                \
    X(DestroyDescriptorUpdateTemplateKHR)             \
    X(UpdateDescriptorSetWithTemplate)                \
    X(UpdateDescriptorSetWithTemplateKHR)

#define CLASTRACE_DECLARE_PFN(name) PFN_vk##name name = nullptr;

// A descriptor the layer follows: a storage or uniform buffer (dispatches' storage_buffers hold
// the storage ones; consumers search both for structure addresses) or an acceleration structure
// (what a consumer can reach).
using TrackedDescriptor = std::variant<BoundStorageBuffer, ReachableAccelerationStructure>;
using DescriptorsOfSet = std::map<std::pair<uint32_t, uint32_t>, TrackedDescriptor>;

struct InstanceDispatch {
    CLASTRACE_INSTANCE_FUNCTIONS(CLASTRACE_DECLARE_PFN)
};
struct DeviceDispatch {
    CLASTRACE_DEVICE_FUNCTIONS(CLASTRACE_DECLARE_PFN)
};

struct InstanceState {
    VkInstance instance = VK_NULL_HANDLE;
    InstanceDispatch next;
    uint32_t api_version = VK_API_VERSION_1_0;
    std::string application_name, engine_name;
};

struct DeviceState {
    VkDevice device = VK_NULL_HANDLE;
    VkPhysicalDevice physical_device = VK_NULL_HANDLE;
    InstanceState* instance = nullptr;
    DeviceDispatch next;
    bool serving = false;          // the layer provides the cluster extension for this device
    bool cluster_enabled = false;  // the application enabled the extension (served or native)
    // VK_EXT_frame_boundary enabled and provided by the layer: its structs never reach the driver.
    bool frame_boundary_served = false;
    bool capturing = false;
    // GPU timestamps around captured commands: CLASTRACE_TIMESTAMPS and every queue family the
    // device was created with has timestampValidBits (a command buffer runs on one of them).
    bool timestamps = false;
    uint64_t timestamp_mask = ~0ull;  // the smallest family's valid bits
    // Executions whose timestamps are still to be read: once the application learns they
    // completed (fence, idle wait), or when their command buffer is reset, freed or re-begun.
    struct PendingTimestampRead {
        VkQueue queue = VK_NULL_HANDLE;
        uint64_t fence = 0;
        uint64_t submission_index = 0;
        uint64_t command_buffer = 0;
        VkQueryPool pool = VK_NULL_HANDLE;
        uint32_t count = 0;
        uint64_t read_pause_id = 0;
        uint32_t occurrence = 0;
    };
    std::mutex timestamps_mutex;
    std::vector<PendingTimestampRead> pending_timestamp_reads;
    // Capture on and still writing (a sink that failed stops the capture work at once).
    bool capturing_now() const { return sink && sink->active(); }
    VkPhysicalDeviceClusterAccelerationStructurePropertiesNV cluster_properties{};
    VkPhysicalDeviceMemoryProperties memory_properties{};
    VkDeviceSize non_coherent_atom_size = 1;
    DeviceMemoryMap memory_map;
    std::shared_ptr<CaptureSink> sink;  // null when not capturing
    std::unique_ptr<PauseWorker> pauses;
    HostWriteWatch host_writes;  // host writes to mapped inputs of submitted commands
    // Held from the check that no other queue uses a submission's shared pause events until the
    // worker expects its pauses (layer_submit.cpp), so two such submissions never overlap there.
    std::mutex shared_pauses_mutex;
    std::atomic<uint64_t> pause_counter{0};
    std::mutex command_buffers_mutex;
    std::unordered_map<VkCommandBuffer, std::shared_ptr<CommandBufferLog>> command_buffers;
    std::unordered_map<VkCommandPool, std::vector<VkCommandBuffer>> pool_command_buffers;
    std::unordered_set<VkCommandBuffer> secondary_command_buffers;
    // Storage-buffer, uniform-buffer and acceleration-structure descriptors written with
    // vkUpdateDescriptorSets (and templates), copied with its copies:
    // set -> (binding, element) -> descriptor.
    std::mutex descriptors_mutex;
    std::unordered_map<VkDescriptorSet, DescriptorsOfSet> descriptors;
    // Descriptor update templates' entries, turned back into writes at each update
    // (descriptor_templates.cpp).
    struct DescriptorTemplate {
        std::vector<VkDescriptorUpdateTemplateEntry> entries;
        VkPipelineBindPoint bind_point = VK_PIPELINE_BIND_POINT_GRAPHICS;  // push templates
    };
    std::unordered_map<uint64_t, DescriptorTemplate> descriptor_templates;
    // VK_EXT_descriptor_buffer: descriptors' bytes, set and pipeline layouts
    // (consumer_descriptor_buffers.cpp).
    DescriptorBufferRegistry descriptor_buffers;
    // KHR structures' device addresses (vkGetAccelerationStructureDeviceAddressKHR answers, or
    // the layer's own asks) and NV structures' handles, both ways: consumers name the structures
    // they reach by handle and address (consumer_commands.cpp).
    std::mutex acceleration_structure_addresses_mutex;
    std::unordered_map<uint64_t, VkDeviceAddress> acceleration_structure_addresses;
    std::unordered_map<VkDeviceAddress, uint64_t> acceleration_structures_by_address;
    // Shader modules and pipelines whose SPIR-V may write through buffer device addresses
    // (spirv_pipelines.cpp), each pipeline with the stages (VkPipelineStageFlags2) of such
    // shaders: a dispatch or draw with one is recorded as a possible writer of all
    // device-address memory.
    std::mutex pipelines_mutex;
    std::unordered_set<uint64_t> address_writing_modules;
    std::unordered_map<uint64_t, VkPipelineStageFlags2> address_writing_pipelines;
    // Likewise for ray queries (SPIR-V RayQueryKHR): modules, and pipelines with their stages.
    std::unordered_set<uint64_t> ray_query_modules;
    std::unordered_map<uint64_t, VkPipelineStageFlags2> ray_query_pipelines;
    // Modules and pipelines whose SPIR-V converts a value that may come from memory into an
    // acceleration structure (OpConvertUToAccelerationStructureKHR): their consumers' bound
    // buffers are searched for structure addresses (consumer_buffer_addresses.cpp).
    std::unordered_set<uint64_t> structure_address_modules;
    std::unordered_set<uint64_t> structure_address_pipelines;
    // The ray check (CLASTRACE_RAY_CHECK): queue families of the queues handed out, the NV ray
    // tracing limits, and the NV structures the capture saw built.
    std::mutex queues_mutex;
    std::unordered_map<VkQueue, uint32_t> queue_families;
    std::unordered_map<VkQueue, uint32_t> queue_indices;  // index within its family
    bool nv_ray_tracing_enabled = false;
    // VK_KHR_ray_query with rayQuery, enabled by the application or by the layer for the ray
    // check of KHR top levels (CLASTRACE_RAY_CHECK).
    bool ray_query_enabled = false;
    // Served cluster BLASes also get the driver's BLAS (traceable_serving.cpp); null: off.
    std::shared_ptr<TraceableDriver> traceable;
    VkPhysicalDeviceRayTracingPropertiesNV ray_tracing_properties_nv{};
    NvSceneModel nv_scene;
    ~DeviceState();
};

// Submissions are counted per process, so indices from several devices never collide in
// the one trace (CLASTRACE_SUBMIT_RANGE counts the same way).
uint64_t next_submission_index();
// The layer's index for a submission whose index a pre-range prelude took (layer_pre_range.h).
uint64_t index_after_prelude(uint64_t prelude_index);
// The application's own count of a layer index (what CLASTRACE_SUBMIT_RANGE and
// FrameBoundary.submission count): the layer's preludes are not the application's submissions.
uint64_t application_submission(uint64_t index);

// Frames (CLASTRACE_FRAME_RANGE; layer_frame_boundary.cpp): the frame a submission made now
// belongs to: vkQueuePresentKHR calls so far in this process, or frame-end VkFrameBoundaryEXT
// marks so far, whichever is ahead (a program marking and presenting each frame counts it once).
uint64_t current_frame();
// A vkQueuePresentKHR call ends a frame: returns the frame it ended.
uint64_t count_present();
const VkFrameBoundaryEXT* find_frame_boundary(const void* chain);
// Records `boundary` (whatever the frame range) and, for a frame end, advances the frame
// counter. `frame` is the frame of the carrying call (current_frame() when a submission was
// made; what count_present() returned for a present).
void frame_boundary_marked(DeviceState& d, VkQueue queue, const VkFrameBoundaryEXT& boundary,
                           FrameBoundaryCarrier carrier, uint64_t submission, uint32_t batch,
                           uint64_t frame);
// Removes `type` from a const pNext chain for the duration of one call, then restores it (a
// null head removes nothing). Not copyable: the restore must happen once.
struct ChainUnlink {
    VkBaseOutStructure* previous = nullptr;
    VkBaseOutStructure* removed = nullptr;
    ChainUnlink(const void* head, VkStructureType type) {
        auto* prev = (VkBaseOutStructure*)head;
        while (prev && prev->pNext) {
            if (prev->pNext->sType == type) {
                previous = prev;
                removed = prev->pNext;
                prev->pNext = removed->pNext;
                return;
            }
            prev = prev->pNext;
        }
    }
    ChainUnlink(const ChainUnlink&) = delete;
    ChainUnlink& operator=(const ChainUnlink&) = delete;
    ~ChainUnlink() {
        if (previous) previous->pNext = removed;
    }
};

// Registries keyed by dispatch key; lookups take a shared lock, creation/destruction exclusive.
InstanceState* find_instance(DispatchKey key);
DeviceState* find_device(DispatchKey key);
void register_instance(DispatchKey key, std::unique_ptr<InstanceState> state);
std::unique_ptr<InstanceState> unregister_instance(DispatchKey key);
void register_device(DispatchKey key, std::unique_ptr<DeviceState> state);
std::unique_ptr<DeviceState> unregister_device(DispatchKey key);

// One line to stderr, prefixed "clastrace: ", when `level` is enabled by CLASTRACE_LOG.
void log_message(LogLevel level, const char* format, ...) __attribute__((format(printf, 2, 3)));

// The process-wide sink (created on first device with capture on); null when capture is off or
// the output cannot be written (the reason was printed once).
std::shared_ptr<CaptureSink> process_capture_sink();

// Interception tables: the layer's function for a name, or null.
PFN_vkVoidFunction intercept_instance_function(const char* name);
PFN_vkVoidFunction intercept_device_function(const char* name, DeviceState* device);

// Defined by the part that owns each group of hooks.
PFN_vkVoidFunction serving_instance_hook(const char* name);
PFN_vkVoidFunction resource_hook(const char* name);
PFN_vkVoidFunction command_hook(const char* name);
PFN_vkVoidFunction pipeline_hook(const char* name);
PFN_vkVoidFunction draw_hook(const char* name);
// The stages of `pipeline` whose shaders may write through buffer device addresses (0: none;
// spirv_pipelines.cpp).
VkPipelineStageFlags2 address_writing_stages(DeviceState& d, uint64_t pipeline);
// Records a draw (`entry_point`) when the bound graphics pipeline may write through device
// addresses (layer_commands.cpp; the draw hooks are in spirv_draws.cpp).
void record_draw_through_addresses(VkCommandBuffer cb, const char* entry_point);
PFN_vkVoidFunction submit_hook(const char* name);
PFN_vkVoidFunction cluster_hook(const char* name);
PFN_vkVoidFunction acceleration_structure_hook(const char* name);
PFN_vkVoidFunction present_hook(const char* name);
PFN_vkVoidFunction sparse_hook(const char* name);
// KHR acceleration-structure builds, copies, property queries and size queries
// (khr_commands.cpp); the layer learns where each KHR structure lives from its creation.
PFN_vkVoidFunction khr_acceleration_structure_hook(const char* name);
void remember_khr_structure(DeviceState& device, const KhrStructureStorage& storage);
void forget_khr_structure(DeviceState& device, uint64_t acceleration_structure);
// vkDestroyDevice: drops the device's KHR structures and property query pools, so a device
// created later (whose state may reuse the address, whose handles may repeat) sees none of them.
void forget_khr_device(const DeviceState& device);
// Where a KHR structure lives ({handle} alone when the layer did not see it created).
KhrStructureStorage khr_structure_storage(const DeviceState& device,
                                          uint64_t acceleration_structure);
// Consumers of acceleration structures (consumer_commands.cpp: rays, push constants and
// descriptors; consumer_pipelines.cpp: ray-tracing pipelines; descriptor_templates.cpp).
PFN_vkVoidFunction consumer_hook(const char* name);
PFN_vkVoidFunction consumer_pipeline_hook(const char* name);
PFN_vkVoidFunction descriptor_template_hook(const char* name);
// VK_EXT_descriptor_buffer (consumer_descriptor_buffers.cpp; consumer_hook asks it).
PFN_vkVoidFunction descriptor_buffer_hook(const char* name);
// The stages of `pipeline` whose shaders use ray queries (0: none; spirv_pipelines.cpp).
VkPipelineStageFlags2 ray_query_stages(DeviceState& d, uint64_t pipeline);
// What the SPIR-V of one shader stage says (spirv_pipelines.cpp): the module's marks, or the
// scan of a VkShaderModuleCreateInfo chained to the stage.
struct ShaderStageMarks {
    bool may_write_through_addresses = false;
    bool uses_ray_queries = false;
    bool converts_addresses_from_memory = false;  // SpirvScan's, when the capture is on
};
// Whether a shader of `pipeline` converts a value that may come from memory into an acceleration
// structure (spirv_pipelines.cpp).
bool converts_structure_addresses_from_memory(DeviceState& d, uint64_t pipeline);
// pipelines_mutex held by the caller of both.
ShaderStageMarks shader_stage_marks(DeviceState& d, const VkPipelineShaderStageCreateInfo& stage);
// Marks `pipeline` with the pipeline stages of its shader stages that write through addresses
// or use ray queries.
void mark_pipeline_stages(DeviceState& d, uint64_t pipeline,
                          const VkPipelineShaderStageCreateInfo* stages, uint32_t stage_count);
// The acceleration structure `handle` (KHR when `khr`, else NV) as a consumer names it: its
// KHR device address (asking the driver once when the application never did) or NV handle;
// 0 when unknown. Remember/forget keep the registry (layer_acceleration_structures.cpp).
VkDeviceAddress acceleration_structure_address(DeviceState& d, uint64_t handle, bool khr);
void remember_acceleration_structure_address(DeviceState& d, uint64_t handle,
                                             VkDeviceAddress address);
void forget_acceleration_structure_address(DeviceState& d, uint64_t handle);
// Follows one descriptor write (vkUpdateDescriptorSets, a template's entry): storage buffers
// and acceleration structures are kept, anything else written there is forgotten.
void track_descriptor_write(DeviceState& d, const VkWriteDescriptorSet& write);
// The acceleration structures of a push-descriptor write at `bind_point` (consumer_commands.cpp).
void track_pushed_descriptor_write(DeviceState& d, VkCommandBuffer cb,
                                   VkPipelineBindPoint bind_point, uint32_t set,
                                   const VkWriteDescriptorSet& write);
// Writes acceleration-structure descriptors of `write` into `set` (descriptors_mutex held),
// resolving each handle's address; false when `write` is not of that type.
bool track_acceleration_structure_write(DeviceState& d, const VkWriteDescriptorSet& write,
                                        DescriptorsOfSet& set);

// Reads again, at submission, the structures each consumer of the submitted command buffers (and
// the secondaries they execute) can reach: sets updated after binding change them between
// recording and submission. A command buffer whose answer changed is handed to the sink again
// (consumer_commands.cpp).
void refresh_consumer_structures(DeviceState& d, const SubmissionRecord& record);

// CLASTRACE_RAY_CHECK: after submission `submissionIndex` on `queue` (just submitted), waits
// for the queue and traces the configured rays against each of `topLevels`, recording a
// RayCheckRecord per top level. Called from the application's vkQueueSubmit.
void run_ray_checks(DeviceState& device, VkQueue queue, uint64_t submission_index,
                    const std::vector<uint64_t>& top_levels);
PFN_vkVoidFunction host_sync_hook(const char* name);

// GPU timestamps (layer_timestamps.cpp): reads, and hands to the sink, the pending executions
// `completed` says have finished (their queries are then final).
void read_completed_timestamps(
    DeviceState& device,
    const std::function<bool(const DeviceState::PendingTimestampRead&)>& completed);

// Serving decisions, shared by the instance hooks and device creation.
bool driver_has_cluster_extension(InstanceState& instance, VkPhysicalDevice physical_device);
// Whether the driver chain below the layer lists device extension `name`.
bool driver_lists_extension(InstanceState& instance, VkPhysicalDevice physical_device,
                            const char* name);
bool should_serve(InstanceState& instance, VkPhysicalDevice physical_device);
// Traceable cluster BLASes (traceable_serving.cpp): the probe at device creation, the served
// size answers, and the driver's build after the engine's in a pause.
void set_up_traceable_clusters(DeviceState& state);
void cover_traceable_blas(DeviceState& state,
                          const VkClusterAccelerationStructureInputInfoNV& input,
                          VkAccelerationStructureBuildSizesInfoKHR& sizes);
// The room each implicit destination object of `command` takes so that the driver's BLAS fits
// at its address (engine::ExecuteOptions::implicit_object_room): a build's worst case, or a
// move's largest moved driver BVH (read through `memory`). 0 where the mode is off or `command`
// writes no cluster BLASes to implicit destinations.
uint64_t traceable_implicit_room(DeviceState& state,
                                 const VkClusterAccelerationStructureCommandsInfoNV& command,
                                 const ServedMemory& memory);
// Reads of the application's memory through `memory` see the engine's bytes of traceable BLASes.
void overlay_traceable_bytes(DeviceState& state, ServedMemory& memory);
void build_traceable_blases(DeviceState& state, uint64_t pause_id,
                            const VkClusterAccelerationStructureCommandsInfoNV& command,
                            const engine::MemoryImage& image, const ServedMemory& memory,
                            const std::vector<engine::OpResult>& ops,
                            std::vector<ClusterBuildCapture::DriverBvh>* driver_bvh);
VkPhysicalDeviceClusterAccelerationStructurePropertiesNV cluster_properties_for(
    InstanceState& instance, VkPhysicalDevice physical_device, bool serving);

}  // namespace clastrace::capture
