// SPDX-License-Identifier: Apache-2.0
// What the capture layer records: plain values, no Vulkan handles kept alive. Handles are
// stored as uint64_t so a trace can name them; device addresses are what the application saw.
#pragma once

#include "clastrace/capture/captured_bytes.h"
#include "clastrace/capture/nv_ray_tracer.h"

#include <clastrace/vk_cluster_abi.h>

#include <cstdint>
#include <functional>
#include <string>
#include <variant>
#include <vector>

namespace clastrace::capture {

// VkClusterAccelerationStructureCommandsInfoNV with its op-specific input copied by value.
// `info.input.opInput` and every pNext are cleared: the copy owns no pointers.
struct ClusterCommandParameters {
    VkClusterAccelerationStructureCommandsInfoNV info{};
    VkClusterAccelerationStructureClustersBottomLevelInputNV bottom_level_input{};
    VkClusterAccelerationStructureTriangleClusterInputNV triangle_cluster_input{};
    VkClusterAccelerationStructureMoveObjectsInputNV move_objects_input{};
    bool has_op_input = false;  // false when the application passed a null op input

    static ClusterCommandParameters copy_of(
        const VkClusterAccelerationStructureCommandsInfoNV& info);
    // The parameters as a driver reads them: opInput pointing into this copy.
    VkClusterAccelerationStructureCommandsInfoNV resolved() const;
};

ClusterCommandParameters copy_cluster_input(const VkClusterAccelerationStructureInputInfoNV& input);

// Which part of a cluster build's input or output a captured range is.
enum class MemoryRole {
    kSrcInfosCount,
    kSrcInfos,
    kIndexBuffer,
    kVertexBuffer,
    kGeometryIndexAndFlags,
    kOpacityMicromapIndices,
    kInstantiationBoundingBox,
    kClusterReferences,
    kIndirectAddress,  // an address read through an INDIRECTED_* address resolution flag
    kDstAddresses,
    kDstSizes,
    kDstObject,
    kTransformData,  // vkCmdBuildAccelerationStructureNV geometry transforms
    kAabbs,
    kInstances,
    kSerializedAccelerationStructure,  // vkCmdCopyMemoryToAccelerationStructureKHR source
    kShaderWrite,                  // exact mode: bytes a dispatch changed through device addresses
    kBuildRanges,                  // KHR indirect builds: the ranges read at execution
    kInstancePointers,             // KHR instances given as an array of pointers
    kSourceAccelerationStructure,  // a KHR update's or copy's source structure
    kTraceRaysIndirect,            // what vkCmdTraceRaysIndirect(2)KHR read at its indirect address
};
const char* memory_role_name(MemoryRole role);

struct CapturedRange {
    MemoryRole role;
    uint32_t entry = 0;  // srcInfosArray entry it belongs to (0 for command-wide ranges)
    VkDeviceAddress address = 0;
    CapturedBytes bytes;
    uint64_t buffer = 0;  // a buffer holding the range, and the range's offset in it
    VkDeviceSize buffer_offset = 0;
};

struct CaptureIssue {
    VkDeviceAddress address = 0;
    uint64_t size = 0;
    std::string rule;  // a VUID verbatim where one applies, else a plain statement
};

struct EngineFindingRecord {
    std::string rule;  // the engine's rule: a VUID verbatim or a CLASTRACE-... name
    std::string message;
    int64_t op_index = -1;
    VkDeviceAddress address = 0;
};

// ---- State the replay needs -------------------------------------------------------------

struct DeviceRecord {
    uint64_t device = 0;
    std::string device_name;
    std::string application_name, engine_name;  // VkApplicationInfo
    uint32_t api_version = 0;
    uint32_t vendor_id = 0, device_id = 0, driver_version = 0, device_type = 0;
    std::vector<uint8_t> pipeline_cache_uuid;
    float timestamp_period = 0;
    std::vector<VkMemoryHeap> memory_heaps;
    std::vector<std::string> enabled_extensions;  // as the application asked, served ones included
    bool served_by_layer = false;
    VkPhysicalDeviceClusterAccelerationStructurePropertiesNV cluster_properties{};
    bool cluster_feature_enabled = false;
    std::vector<VkMemoryType> memory_types;
    // VkPhysicalDeviceDriverProperties / VkPhysicalDeviceIDProperties (Vulkan 1.2 devices): the
    // header of a serialized acceleration structure names the driver that wrote it.
    uint32_t driver_id = 0;
    std::string driver_name, driver_info;
    std::vector<uint8_t> driver_uuid, device_uuid;
    bool has_ray_tracing_properties_nv = false;  // the device has VK_NV_ray_tracing
    VkPhysicalDeviceRayTracingPropertiesNV ray_tracing_properties_nv{};
};

struct MemoryRecord {
    uint64_t memory = 0;
    VkDeviceSize size = 0;
    uint32_t type_index = 0;
    VkMemoryPropertyFlags property_flags = 0;
    VkMemoryAllocateFlags allocate_flags = 0;
};

struct BufferRecord {
    uint64_t buffer = 0;
    VkDeviceSize size = 0;
    VkBufferUsageFlags usage = 0;
    VkBufferCreateFlags flags = 0;
    VkSharingMode sharing_mode = VK_SHARING_MODE_EXCLUSIVE;
    std::vector<uint32_t> queue_families;
};

struct BufferBindingRecord {
    uint64_t buffer = 0;
    uint64_t memory = 0;
    VkDeviceSize offset = 0;
};

struct BufferAddressRecord {
    uint64_t buffer = 0;
    VkDeviceAddress address = 0;
};

struct BuildSizesQuery {
    uint64_t device = 0;
    ClusterCommandParameters input;  // only `info.input` and the op input are meaningful
    VkAccelerationStructureBuildSizesInfoKHR answer{};
    bool answered_by_layer = false;  // true: the layer's model; false: the driver's answer
};

// vkCreateAccelerationStructureNV / vkCreateAccelerationStructureKHR.
struct AccelerationStructureRecord {
    uint64_t acceleration_structure = 0;
    bool khr = false;
    uint32_t type = 0;    // VkAccelerationStructureTypeKHR/NV
    uint64_t buffer = 0;  // KHR: where it lives
    VkDeviceSize offset = 0, size = 0;
    uint32_t create_flags = 0;
    VkDeviceSize compacted_size = 0;  // NV
    uint32_t info_type = 0, info_flags = 0,
             instance_count = 0;           // NV: VkAccelerationStructureInfoNV
    std::vector<VkGeometryNV> geometries;  // pNext cleared
};
struct AccelerationStructureBindingRecord {  // vkBindAccelerationStructureMemoryNV
    uint64_t acceleration_structure = 0;
    uint64_t memory = 0;
    VkDeviceSize offset = 0;
};
// vkGetAccelerationStructureHandleNV (the 64-bit handle instance records name) or
// vkGetAccelerationStructureDeviceAddressKHR.
struct AccelerationStructureAddressRecord {
    uint64_t acceleration_structure = 0;
    uint64_t address = 0;
};
struct
    AccelerationStructureMemoryRequirementsRecord {  // vkGetAccelerationStructureMemoryRequirementsNV
    uint64_t acceleration_structure = 0;
    uint32_t type = 0;  // VkAccelerationStructureMemoryRequirementsTypeNV
    VkDeviceSize size = 0, alignment = 0;
    uint32_t memory_type_bits = 0;
};

// CLASTRACE_RAY_CHECK: rays the layer traced against a top level after the submission that
// built it completed, and the driver's answers (see capture/README.md, "Ray check").
struct RayCheckRecord {
    uint64_t acceleration_structure = 0;
    uint64_t device_handle = 0;
    uint64_t submission_index = 0;  // the layer's index; the trace sink maps it to the trace's
    std::vector<NvTracedRay> rays;
    std::vector<NvRayHit> hits;
    std::string label;
};

// ---- Commands ---------------------------------------------------------------------------

struct BufferBarrier {
    uint64_t src_stage = 0, src_access = 0, dst_stage = 0, dst_access = 0;
    uint64_t buffer = 0;
    VkDeviceSize offset = 0, size = 0;
};
struct MemoryBarrier {
    uint64_t src_stage = 0, src_access = 0, dst_stage = 0, dst_access = 0;
};

struct BarrierCommand {
    bool synchronization2 = false;
    uint64_t src_stage_mask = 0, dst_stage_mask = 0;  // v1 only; v2 carries stages per barrier
    VkDependencyFlags dependency_flags = 0;
    std::vector<MemoryBarrier> memory_barriers;
    std::vector<BufferBarrier> buffer_barriers;
    uint32_t image_barrier_count = 0;  // images are not modelled; counted so the trace is honest
};

struct EventCommand {
    enum class Kind { kSet, kReset, kWait } kind = Kind::kSet;
    bool synchronization2 = false;
    std::vector<uint64_t> events;
    uint64_t src_stage_mask = 0, dst_stage_mask = 0;
    std::vector<MemoryBarrier> memory_barriers;
    std::vector<BufferBarrier> buffer_barriers;
};

struct CopyBufferCommand {
    uint64_t src = 0, dst = 0;
    std::vector<VkBufferCopy> regions;
};

struct FillBufferCommand {
    uint64_t dst = 0;
    VkDeviceSize offset = 0, size = 0;
    uint32_t data = 0;
};

struct UpdateBufferCommand {
    uint64_t dst = 0;
    VkDeviceSize offset = 0;
    std::vector<uint8_t> data;
};

// One storage-buffer descriptor visible to a dispatch (dynamic offsets applied). The layer keeps
// uniform buffers in it too (`type`), searched for consumers' structure addresses only.
struct BoundStorageBuffer {
    uint32_t set = 0, binding = 0, array_element = 0;
    VkDescriptorType type = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    uint64_t buffer = 0;
    VkDeviceSize offset = 0, range = 0;
    VkDeviceAddress address = 0;  // buffer address + offset, when the buffer's address is known
};

// An acceleration structure a consumer (rays, ray queries) can reach through what it binds.
struct ReachableAccelerationStructure {
    enum class Source : uint32_t {
        kDescriptorSet = 0,
        kPushDescriptor = 1,
        kDescriptorBuffer = 2,  // a vkGetDescriptorEXT answer read from a descriptor buffer
        kPushConstants = 3,     // an 8-byte push-constant value equal to a known address
        // An 8-byte value equal to a known address in a storage or uniform buffer bound to a
        // consumer whose shader converts values from memory into structures
        // (consumer_buffer_addresses.cpp).
        kMemory = 4,
    };
    uint32_t set = 0, binding = 0, array_element = 0;
    Source source = Source::kDescriptorSet;
    uint64_t acceleration_structure = 0;  // handle; 0 when only the address is known
    VkDeviceAddress address = 0;          // KHR device address, NV handle; 0 when unknown
};

struct DispatchCommand {
    uint32_t group_count_x = 0, group_count_y = 0, group_count_z = 0;
    uint64_t pipeline = 0;
    uint64_t indirect_buffer = 0;  // vkCmdDispatchIndirect
    VkDeviceSize indirect_offset = 0;
    std::vector<BoundStorageBuffer> storage_buffers;  // from vkUpdateDescriptorSets writes
    // The pipeline's SPIR-V uses physical storage buffer pointers (spirv_scan.h): the dispatch
    // may write any device-address memory.
    bool may_write_device_addresses = false;
    // CLASTRACE_DEVICE_ADDRESS_WRITES=exact: the pauses around it (0: none); links the dispatch
    // to the ClusterBuildCapture (kind kDeviceAddressWrites) of each execution.
    uint64_t pause_id = 0;
    // The pipeline's SPIR-V uses ray queries: the structures the dispatch can reach.
    bool ray_query = false;
    std::vector<ReachableAccelerationStructure> acceleration_structures;
};

// A draw whose graphics pipeline may write through buffer device addresses or uses ray queries
// (only such draws are recorded).
struct DrawCommand {
    uint64_t pipeline = 0;
    const char* entry_point = "";              // "vkCmdDraw", "vkCmdDrawMeshTasksEXT", ... (static)
    VkPipelineStageFlags2 address_stages = 0;  // stages whose shaders use addresses
    VkPipelineStageFlags2 ray_query_stages = 0;  // stages whose shaders use ray queries
    std::vector<ReachableAccelerationStructure> acceleration_structures;
};

// vkCmdTraceRaysKHR, ...IndirectKHR, ...Indirect2KHR, vkCmdTraceRaysNV.
struct TraceRaysCommand {
    uint64_t pipeline = 0;
    const char* entry_point = "";  // "vkCmdTraceRaysKHR", ... (static)
    uint32_t width = 0, height = 0, depth = 0;
    VkDeviceAddress indirect_address = 0;  // the indirect forms
    // raygen, miss, hit, callable; zero for Indirect2KHR (they are in its indirect struct)
    VkStridedDeviceAddressRegionKHR shader_binding_tables[4] = {};
    std::vector<ReachableAccelerationStructure> acceleration_structures;
    std::vector<BoundStorageBuffer> storage_buffers;
    // A shader of the pipeline uses physical storage buffer pointers (spirv_scan.h).
    bool may_write_device_addresses = false;
    // The indirect forms under capture: the pause before the rays reads the parameters
    // (`indirect_size` bytes at `indirect_address`); 0 otherwise.
    uint64_t pause_id = 0;
    uint32_t indirect_size = 0;
};

struct ClusterBuildCommand {
    ClusterCommandParameters parameters;
    uint64_t pause_id = 0;           // links this command to its ClusterBuildCapture
    bool executed_by_layer = false;  // serving: the driver never sees this command
};

struct BuildAccelerationStructureNVCommand {
    VkAccelerationStructureTypeNV type{};
    VkBuildAccelerationStructureFlagsNV flags = 0;
    uint32_t instance_count = 0;
    std::vector<VkGeometryNV> geometries;  // pNext cleared
    uint64_t instance_data = 0;
    VkDeviceSize instance_offset = 0;
    VkBool32 update = VK_FALSE;
    uint64_t dst = 0, src = 0, scratch = 0;
    VkDeviceSize scratch_offset = 0;
    uint64_t pause_id = 0;  // 0: recorded without capture
};

struct CopyMemoryToAccelerationStructureCommand {
    VkDeviceAddress src = 0;
    uint64_t dst = 0;
    VkCopyAccelerationStructureModeKHR mode{};
    uint64_t pause_id = 0;
};

// A timestamp the layer wrote around a captured command (into its own query pool, which the
// application never sees). Its ticks arrive with the capture of `readPauseId`: the pause the
// layer put at the end of the command buffer, where the queue waits while they are read.
struct TimestampWriteCommand {
    uint64_t query_pool = 0;
    uint32_t query = 0;
    uint64_t stage_mask =
        0;  // VkPipelineStageFlags2 value (the sync1 bits used have the same value)
    uint64_t read_pause_id = 0;
};

// vkCmdExecuteCommands: the secondaries run, in this order, as they are recorded when the
// primary is submitted (a secondary cannot be re-recorded while a primary holding it is pending).
struct ExecuteCommandsCommand {
    std::vector<uint64_t> secondaries;
};

// ---- KHR acceleration structures in use (khr_commands.cpp) ---------------------------------

// Where a KHR acceleration structure lives (vkCreateAccelerationStructureKHR): its storage is
// read from there when a command reads the structure (an update's source, a copy's source).
struct KhrStructureStorage {
    uint64_t acceleration_structure = 0;
    uint64_t buffer = 0;  // 0: unknown (created before the layer saw it)
    VkDeviceSize offset = 0, size = 0;
};

// VkAccelerationStructureBuildGeometryInfoKHR copied by value, geometries flattened from
// pGeometries or ppGeometries (pNext cleared; the chain's sTypes kept in next_stypes).
struct KhrBuildInfo {
    VkAccelerationStructureBuildGeometryInfoKHR info{};  // pGeometries/ppGeometries/pNext null
    std::vector<VkAccelerationStructureGeometryKHR> geometries;
    // The direct command's ranges, one per geometry; empty for an indirect build (read at
    // execution from indirect_address, see ClusterBuildCapture::khr_indirect_ranges).
    std::vector<VkAccelerationStructureBuildRangeInfoKHR> ranges;
    VkDeviceAddress indirect_address = 0;
    uint32_t indirect_stride = 0;
    std::vector<uint32_t> max_primitive_counts;  // indirect builds and size queries
    std::vector<uint32_t> next_stypes;
    KhrStructureStorage update_source;  // mode UPDATE: where srcAccelerationStructure lives

    static KhrBuildInfo copy_of(const VkAccelerationStructureBuildGeometryInfoKHR& info,
                                const VkAccelerationStructureBuildRangeInfoKHR* ranges);
    // The info as a driver reads it: pGeometries pointing into this copy.
    VkAccelerationStructureBuildGeometryInfoKHR resolved() const;
};

// vkCmdBuildAccelerationStructuresKHR / vkCmdBuildAccelerationStructuresIndirectKHR.
struct BuildAccelerationStructuresKHRCommand {
    bool indirect = false;
    std::vector<KhrBuildInfo> infos;
    uint64_t pause_id = 0;  // 0: recorded without capture
};

// vkCmdCopyAccelerationStructureKHR/NV and vkCmdCopyAccelerationStructureToMemoryKHR.
struct CopyAccelerationStructureCommand {
    bool khr = true;
    bool to_memory = false;  // vkCmdCopyAccelerationStructureToMemoryKHR: dst_address is set
    uint64_t src = 0, dst = 0;
    VkDeviceAddress dst_address = 0;
    VkCopyAccelerationStructureModeKHR mode{};
    KhrStructureStorage source;  // where src lives (KHR only)
    uint64_t pause_id = 0;
};

// vkCmdWriteAccelerationStructuresPropertiesKHR/NV.
struct WriteAccelerationStructuresPropertiesCommand {
    bool khr = true;
    std::vector<uint64_t> acceleration_structures;
    VkQueryType query_type{};
    uint64_t query_pool = 0;
    uint32_t first_query = 0;
};

// vkGetQueryPoolResults of a pool that holds acceleration-structure property queries.
struct QueryPoolResultsRecord {
    uint64_t query_pool = 0;
    uint32_t first_query = 0;
    std::vector<uint64_t> values;  // each query's value (and availability word, if asked)
    int32_t result = 0;
};

// vkGetAccelerationStructureBuildSizesKHR and the driver's answer.
struct KhrBuildSizesQuery {
    VkAccelerationStructureBuildTypeKHR build_type{};
    KhrBuildInfo info;
    std::vector<uint32_t> max_primitive_counts;
    VkAccelerationStructureBuildSizesInfoKHR answer{};
};

using RecordedCommand =
    std::variant<BarrierCommand, EventCommand, CopyBufferCommand, FillBufferCommand,
                 UpdateBufferCommand, DispatchCommand, ClusterBuildCommand,
                 BuildAccelerationStructureNVCommand, CopyMemoryToAccelerationStructureCommand,
                 TimestampWriteCommand, ExecuteCommandsCommand, DrawCommand,
                 BuildAccelerationStructuresKHRCommand, CopyAccelerationStructureCommand,
                 WriteAccelerationStructuresPropertiesCommand, TraceRaysCommand>;

struct RecordedCommandBuffer {
    uint64_t command_buffer = 0;
    VkCommandBufferUsageFlags usage = 0;
    bool secondary = false;
    std::vector<RecordedCommand> commands;
};

// ---- Submissions and execution ------------------------------------------------------------

struct SemaphoreUse {
    uint64_t semaphore = 0;
    uint64_t value = 0;  // timeline value; 0 for binary semaphores
    uint64_t stage_mask = 0;
};

struct SubmitBatch {
    std::vector<SemaphoreUse> waits;
    std::vector<uint64_t> command_buffers;
    std::vector<SemaphoreUse> signals;
};

struct SubmissionRecord {
    uint64_t index = 0;  // per-device submission counter, as CLASTRACE_SUBMIT_RANGE counts
    uint64_t queue = 0;
    uint32_t queue_family =
        0;  // from vkGetDeviceQueue[2]; 0 for a queue the layer never saw handed out
    uint32_t queue_index = 0;
    bool synchronization2 = false;
    std::vector<SubmitBatch> batches;
    uint64_t fence = 0;
    // What the layer could not do exactly for this submission; written as CaptureFindings.
    struct Note {
        uint64_t command_buffer = 0;
        std::string rule;  // CLASTRACE-*
        std::string message;
    };
    std::vector<Note> notes;
};

// vkQueuePresentKHR: ends frame `frame` (frames count presents per process, from 0).
struct PresentRecord {
    uint64_t queue = 0;
    uint64_t frame = 0;
    std::vector<uint64_t>
        wait_semaphores;  // binary: the presentation engine consumes their signals
    std::vector<uint64_t> swapchains;
    std::vector<uint32_t> image_indices;
    int32_t result = 0;
};

// vkAcquireNextImageKHR / vkAcquireNextImage2KHR: a successful one is the presentation
// engine's signal of `semaphore` and `fence` (replay's wait on the semaphore is then satisfied).
struct AcquireRecord {
    uint64_t swapchain = 0;
    uint64_t timeout = 0;
    uint64_t semaphore = 0;
    uint64_t fence = 0;
    uint32_t image_index = 0;
    int32_t result = 0;
    uint32_t device_mask = 0;  // vkAcquireNextImage2KHR only
};

// vkQueueBindSparse as the application called it: a view of its arguments, valid only during the
// sink's sparse_bound() call (the sink encodes it there, traces/sparse_conversions.h).
struct SparseBindRecord {
    VkQueue queue = VK_NULL_HANDLE;
    const VkBindSparseInfo* infos = nullptr;
    uint32_t info_count = 0;
    VkFence fence = VK_NULL_HANDLE;
    VkResult result = VK_SUCCESS;
    // A sparse buffer's device address (0 when the application never asked for it).
    std::function<uint64_t(VkBuffer)> address_of;
};

// A host call that synchronizes with the device: replay needs them to know which submissions
// had completed when the host next wrote memory (FenceWait) or what the host signalled.
struct HostSyncRecord {
    enum class Kind {
        kEventSet,
        kEventReset,
        kEventStatus,  // vkSetEvent / vkResetEvent / vkGetEventStatus
        kFenceWait,
        kFenceReset,
        kFenceStatus,  // vkWaitForFences / vkResetFences / vkGetFenceStatus
        kQueueWaitIdle,
        kDeviceWaitIdle,
        kSemaphoreSignal,
        kSemaphoreWait,  // vkSignalSemaphore / vkWaitSemaphores
    };
    Kind kind = Kind::kFenceWait;
    std::vector<uint64_t> handles;  // events, fences, semaphores, or the queue of QueueWaitIdle
    std::vector<uint64_t> values;   // timeline values of SemaphoreSignal/SemaphoreWait
    bool wait_all = true;  // FenceWait waitAll; SemaphoreWait without VK_SEMAPHORE_WAIT_ANY_BIT
    uint64_t timeout = 0;
    int32_t result = 0;  // the call's VkResult (EventStatus: VK_EVENT_SET/VK_EVENT_RESET)
};

// Mapped memory a submitted command reads, found changed by the host after vkQueueSubmit
// (capture/README.md, "Host writes"): written as a MemoryObservation where the layer saw it,
// before the host call (a wait, the next submission) that saw it.
enum class HostWriteSeen : uint32_t {
    kAtSubmit = 0,       // before a later submission, while the reading one may still run
    kAtWait = 3,         // at the host wait that orders the reading submission
    kReadByCommand = 4,  // at that wait, and the command itself read the changed bytes
};

struct HostWriteRecord {
    HostWriteSeen seen = HostWriteSeen::kAtWait;
    uint64_t memory = 0;
    VkDeviceSize memory_offset = 0;
    uint64_t buffer = 0;  // a buffer holding the range, and its offset there
    VkDeviceSize buffer_offset = 0;
    VkDeviceAddress address = 0;
    std::vector<uint8_t> bytes;     // what the range holds now
    uint64_t submission_index = 0;  // the layer's index of the submission that reads the range
    uint64_t pause_id = 0;          // its command (ClusterBuildCommand::pause_id)
};

// Everything one vkCmdBuildClusterAccelerationStructureIndirectNV read, as it was when the
// command executed on the queue, and everything it wrote, read after it completed.
// Timestamps: not a command but the readback of one command buffer's timestamps (ticks below).
enum class CapturedCommandKind {
    kClusterBuild,
    kBuildAccelerationStructureNv,
    kCopyMemoryToAccelerationStructure,
    kTimestamps,
    kDeviceAddressWrites,  // exact mode: `outputs` are the bytes a dispatch changed (new bytes)
    kBuildAccelerationStructuresKhr,
    kCopyAccelerationStructure,
    kTraceRays,
};

struct ClusterBuildCapture {
    CapturedCommandKind kind =
        CapturedCommandKind::kClusterBuild;  // parameters apply to ClusterBuild only
    uint64_t pause_id = 0;
    uint32_t occurrence = 0;  // nth execution of this command in its submission (simultaneous use)
    uint64_t submission_index = 0;
    uint64_t command_buffer = 0;
    ClusterCommandParameters parameters;
    uint32_t executed_count = 0;  // min(srcInfosCount value, maxAccelerationStructureCount)
    std::vector<CapturedRange> inputs;
    std::vector<CapturedRange> outputs;
    std::vector<CaptureIssue> issues;
    // Serving: the command ran in clastrace's engine (its outputs are what the engine wrote),
    // and what the engine found wrong with it.
    bool executed_by_engine = false;
    std::vector<EngineFindingRecord> engine_findings;
    double pause_milliseconds = 0;  // queue stall the capture caused (both pauses)
    uint64_t compared_bytes = 0;    // kDeviceAddressWrites: bytes compared across the pauses
    // Timestamps: the ticks of queries 0..n-1 of the command buffer's layer-owned pool, masked
    // to the queue's valid bits; valid false where the driver reported no result.
    std::vector<uint64_t> timestamp_ticks;
    std::vector<bool> timestamp_valid;
    // A served build's record leaves the pause worker unfinished: its outputs are still to be
    // walked in the engine's image (which this holds, `heldBytes` of it) and its ranges named by
    // the buffers of its pause. Whoever writes the record calls this first, on its own thread,
    // so the worker is free for the next pause. Empty for every other record. Once it ran, the
    // outputs are views into that image and keep it (still `heldBytes`) until they are freed.
    std::function<void(ClusterBuildCapture&)> complete;
    uint64_t held_bytes = 0;
    // vkCmdBuildAccelerationStructuresIndirectKHR: each info's ranges as read at execution.
    std::vector<std::vector<VkAccelerationStructureBuildRangeInfoKHR>> khr_indirect_ranges;
    // Served traceable cluster BLASes: where the driver's BVH was written (address, size), so
    // replay tells it from the engine's bytes (CmdBuildClusterAccelerationStructureIndirect
    // .driver_bvh).
    struct DriverBvh {
        uint64_t address = 0;
        uint64_t size = 0;
    };
    std::vector<DriverBvh> driver_bvh;
    // Served traceable cluster BLASes at implicit destinations: the room each object took
    // (engine::ExecuteOptions::implicit_object_room; ...Indirect.implicit_object_room). 0: none.
    uint64_t implicit_object_room = 0;
};

// VkFrameBoundaryEXT (VK_EXT_frame_boundary) chained to a submission or a present: a headless
// program's frame marks (layer_frame_boundary.cpp). `frame` is the frame the carrying
// call belongs to (the one a frame-end mark ends).
enum class FrameBoundaryCarrier : uint32_t {
    kSubmit = 0,
    kSubmit2 = 1,
    kPresent = 2,
    kBindSparse = 3
};
struct FrameBoundaryRecord {
    uint64_t queue = 0;
    FrameBoundaryCarrier carrier = FrameBoundaryCarrier::kSubmit;
    uint64_t submission = 0;  // submissions only
    uint32_t batch = 0;       // which info of the call carried it
    uint32_t flags = 0;       // VkFrameBoundaryFlagsEXT
    uint64_t frame_id = 0;
    uint64_t frame = 0;
    std::vector<uint64_t> images;
    std::vector<uint64_t> buffers;
    uint64_t tag_name = 0;
    std::vector<uint8_t> tag;
};

// The start of a frame range that carries the state replay needs from before it
// (layer_pre_range.cpp): `structures` acceleration structures rebuilt by `commands` commands
// (`cluster_commands` of them cluster builds) of the prelude submission `prelude_submission`
// (SubmissionRecord::index) that follows on `queue`, from `bytes` input bytes read before frame
// `first_frame`. Written as a PreRangeState record (docs/trace-format.md) just before the
// prelude's QueueSubmit.
struct PreRangeStateRecord {
    uint64_t queue = 0;
    uint64_t first_frame = 0;
    uint64_t prelude_submission = 0;
    uint32_t structures = 0;
    uint32_t commands = 0;
    uint32_t cluster_commands = 0;
    uint64_t bytes = 0;
};

}  // namespace clastrace::capture
