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
  VkClusterAccelerationStructureClustersBottomLevelInputNV bottomLevelInput{};
  VkClusterAccelerationStructureTriangleClusterInputNV triangleClusterInput{};
  VkClusterAccelerationStructureMoveObjectsInputNV moveObjectsInput{};
  bool hasOpInput = false;  // false when the application passed a null op input

  static ClusterCommandParameters copyOf(const VkClusterAccelerationStructureCommandsInfoNV& info);
  // The parameters as a driver reads them: opInput pointing into this copy.
  VkClusterAccelerationStructureCommandsInfoNV resolved() const;
};

ClusterCommandParameters copyClusterInput(const VkClusterAccelerationStructureInputInfoNV& input);

// Which part of a cluster build's input or output a captured range is.
enum class MemoryRole {
  SrcInfosCount,
  SrcInfos,
  IndexBuffer,
  VertexBuffer,
  GeometryIndexAndFlags,
  OpacityMicromapIndices,
  InstantiationBoundingBox,
  ClusterReferences,
  IndirectAddress,   // an address read through an INDIRECTED_* address resolution flag
  DstAddresses,
  DstSizes,
  DstObject,
  TransformData,      // vkCmdBuildAccelerationStructureNV geometry transforms
  Aabbs,
  Instances,
  SerializedAccelerationStructure,  // vkCmdCopyMemoryToAccelerationStructureKHR source
};
const char* memoryRoleName(MemoryRole role);

struct CapturedRange {
  MemoryRole role;
  uint32_t entry = 0;  // srcInfosArray entry it belongs to (0 for command-wide ranges)
  VkDeviceAddress address = 0;
  CapturedBytes bytes;
  uint64_t buffer = 0;        // a buffer holding the range, and the range's offset in it
  VkDeviceSize bufferOffset = 0;
};

struct CaptureIssue {
  VkDeviceAddress address = 0;
  uint64_t size = 0;
  std::string rule;  // a VUID verbatim where one applies, else a plain statement
};

struct EngineFindingRecord {
  std::string rule;  // the engine's rule: a VUID verbatim or a CLASTRACE-... name
  std::string message;
  int64_t opIndex = -1;
  VkDeviceAddress address = 0;
};

// ---- State the replay needs -------------------------------------------------------------

struct DeviceRecord {
  uint64_t device = 0;
  std::string deviceName;
  std::string applicationName, engineName;  // VkApplicationInfo
  uint32_t apiVersion = 0;
  uint32_t vendorId = 0, deviceId = 0, driverVersion = 0, deviceType = 0;
  std::vector<uint8_t> pipelineCacheUuid;
  float timestampPeriod = 0;
  std::vector<VkMemoryHeap> memoryHeaps;
  std::vector<std::string> enabledExtensions;  // as the application asked, served ones included
  bool servedByLayer = false;
  VkPhysicalDeviceClusterAccelerationStructurePropertiesNV clusterProperties{};
  bool clusterFeatureEnabled = false;
  std::vector<VkMemoryType> memoryTypes;
  // VkPhysicalDeviceDriverProperties / VkPhysicalDeviceIDProperties (Vulkan 1.2 devices): the
  // header of a serialized acceleration structure names the driver that wrote it.
  uint32_t driverId = 0;
  std::string driverName, driverInfo;
  std::vector<uint8_t> driverUuid, deviceUuid;
  bool hasRayTracingPropertiesNV = false;  // the device has VK_NV_ray_tracing
  VkPhysicalDeviceRayTracingPropertiesNV rayTracingPropertiesNV{};
};

struct MemoryRecord {
  uint64_t memory = 0;
  VkDeviceSize size = 0;
  uint32_t typeIndex = 0;
  VkMemoryPropertyFlags propertyFlags = 0;
  VkMemoryAllocateFlags allocateFlags = 0;
};

struct BufferRecord {
  uint64_t buffer = 0;
  VkDeviceSize size = 0;
  VkBufferUsageFlags usage = 0;
  VkBufferCreateFlags flags = 0;
  VkSharingMode sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  std::vector<uint32_t> queueFamilies;
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
  bool answeredByLayer = false;  // true: the layer's model; false: the driver's answer
};

// vkCreateAccelerationStructureNV / vkCreateAccelerationStructureKHR.
struct AccelerationStructureRecord {
  uint64_t accelerationStructure = 0;
  bool khr = false;
  uint32_t type = 0;  // VkAccelerationStructureTypeKHR/NV
  uint64_t buffer = 0;  // KHR: where it lives
  VkDeviceSize offset = 0, size = 0;
  uint32_t createFlags = 0;
  VkDeviceSize compactedSize = 0;  // NV
  uint32_t infoType = 0, infoFlags = 0, instanceCount = 0;  // NV: VkAccelerationStructureInfoNV
  std::vector<VkGeometryNV> geometries;                     // pNext cleared
};
struct AccelerationStructureBindingRecord {  // vkBindAccelerationStructureMemoryNV
  uint64_t accelerationStructure = 0;
  uint64_t memory = 0;
  VkDeviceSize offset = 0;
};
// vkGetAccelerationStructureHandleNV (the 64-bit handle instance records name) or
// vkGetAccelerationStructureDeviceAddressKHR.
struct AccelerationStructureAddressRecord {
  uint64_t accelerationStructure = 0;
  uint64_t address = 0;
};
struct AccelerationStructureMemoryRequirementsRecord {  // vkGetAccelerationStructureMemoryRequirementsNV
  uint64_t accelerationStructure = 0;
  uint32_t type = 0;  // VkAccelerationStructureMemoryRequirementsTypeNV
  VkDeviceSize size = 0, alignment = 0;
  uint32_t memoryTypeBits = 0;
};

// CLASTRACE_RAY_CHECK: rays the layer traced against a top level after the submission that
// built it completed, and the driver's answers (see capture/README.md, "Ray check").
struct RayCheckRecord {
  uint64_t accelerationStructure = 0;
  uint64_t deviceHandle = 0;
  uint64_t submissionIndex = 0;  // the layer's index; the trace sink maps it to the trace's
  std::vector<NvTracedRay> rays;
  std::vector<NvRayHit> hits;
  std::string label;
};

// ---- Commands ---------------------------------------------------------------------------

struct BufferBarrier {
  uint64_t srcStage = 0, srcAccess = 0, dstStage = 0, dstAccess = 0;
  uint64_t buffer = 0;
  VkDeviceSize offset = 0, size = 0;
};
struct MemoryBarrier {
  uint64_t srcStage = 0, srcAccess = 0, dstStage = 0, dstAccess = 0;
};

struct BarrierCommand {
  bool synchronization2 = false;
  uint64_t srcStageMask = 0, dstStageMask = 0;  // v1 only; v2 carries stages per barrier
  VkDependencyFlags dependencyFlags = 0;
  std::vector<MemoryBarrier> memoryBarriers;
  std::vector<BufferBarrier> bufferBarriers;
  uint32_t imageBarrierCount = 0;  // images are not modelled; counted so the trace is honest
};

struct EventCommand {
  enum class Kind { Set, Reset, Wait } kind = Kind::Set;
  bool synchronization2 = false;
  std::vector<uint64_t> events;
  uint64_t srcStageMask = 0, dstStageMask = 0;
  std::vector<MemoryBarrier> memoryBarriers;
  std::vector<BufferBarrier> bufferBarriers;
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

// One storage-buffer descriptor visible to a dispatch (dynamic offsets applied).
struct BoundStorageBuffer {
  uint32_t set = 0, binding = 0, arrayElement = 0;
  VkDescriptorType type = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
  uint64_t buffer = 0;
  VkDeviceSize offset = 0, range = 0;
  VkDeviceAddress address = 0;  // buffer address + offset, when the buffer's address is known
};

struct DispatchCommand {
  uint32_t groupCountX = 0, groupCountY = 0, groupCountZ = 0;
  uint64_t pipeline = 0;
  uint64_t indirectBuffer = 0;  // vkCmdDispatchIndirect
  VkDeviceSize indirectOffset = 0;
  std::vector<BoundStorageBuffer> storageBuffers;  // from vkUpdateDescriptorSets writes
};

struct ClusterBuildCommand {
  ClusterCommandParameters parameters;
  uint64_t pauseId = 0;          // links this command to its ClusterBuildCapture
  bool executedByLayer = false;  // serving: the driver never sees this command
};

struct BuildAccelerationStructureNVCommand {
  VkAccelerationStructureTypeNV type{};
  VkBuildAccelerationStructureFlagsNV flags = 0;
  uint32_t instanceCount = 0;
  std::vector<VkGeometryNV> geometries;  // pNext cleared
  uint64_t instanceData = 0;
  VkDeviceSize instanceOffset = 0;
  VkBool32 update = VK_FALSE;
  uint64_t dst = 0, src = 0, scratch = 0;
  VkDeviceSize scratchOffset = 0;
  uint64_t pauseId = 0;  // 0: recorded without capture
};

struct CopyMemoryToAccelerationStructureCommand {
  VkDeviceAddress src = 0;
  uint64_t dst = 0;
  VkCopyAccelerationStructureModeKHR mode{};
  uint64_t pauseId = 0;
};

// A timestamp the layer wrote around a captured command (into its own query pool, which the
// application never sees). Its ticks arrive with the capture of `readPauseId`: the pause the
// layer put at the end of the command buffer, where the queue waits while they are read.
struct TimestampWriteCommand {
  uint64_t queryPool = 0;
  uint32_t query = 0;
  uint64_t stageMask = 0;  // VkPipelineStageFlags2 value (the sync1 bits used have the same value)
  uint64_t readPauseId = 0;
};

// vkCmdExecuteCommands: the secondaries run, in this order, as they are recorded when the
// primary is submitted (a secondary cannot be re-recorded while a primary holding it is pending).
struct ExecuteCommandsCommand {
  std::vector<uint64_t> secondaries;
};

using RecordedCommand =
    std::variant<BarrierCommand, EventCommand, CopyBufferCommand, FillBufferCommand, UpdateBufferCommand,
                 DispatchCommand, ClusterBuildCommand, BuildAccelerationStructureNVCommand,
                 CopyMemoryToAccelerationStructureCommand, TimestampWriteCommand, ExecuteCommandsCommand>;

struct RecordedCommandBuffer {
  uint64_t commandBuffer = 0;
  VkCommandBufferUsageFlags usage = 0;
  bool secondary = false;
  std::vector<RecordedCommand> commands;
};

// ---- Submissions and execution ------------------------------------------------------------

struct SemaphoreUse {
  uint64_t semaphore = 0;
  uint64_t value = 0;  // timeline value; 0 for binary semaphores
  uint64_t stageMask = 0;
};

struct SubmitBatch {
  std::vector<SemaphoreUse> waits;
  std::vector<uint64_t> commandBuffers;
  std::vector<SemaphoreUse> signals;
};

struct SubmissionRecord {
  uint64_t index = 0;  // per-device submission counter, as CLASTRACE_SUBMIT_RANGE counts
  uint64_t queue = 0;
  uint32_t queueFamily = 0;  // from vkGetDeviceQueue[2]; 0 for a queue the layer never saw handed out
  uint32_t queueIndex = 0;
  bool synchronization2 = false;
  std::vector<SubmitBatch> batches;
  uint64_t fence = 0;
  // What the layer could not do exactly for this submission; written as CaptureFindings.
  struct Note {
    uint64_t commandBuffer = 0;
    std::string rule;  // CLASTRACE-*
    std::string message;
  };
  std::vector<Note> notes;
};

// vkQueuePresentKHR: ends frame `frame` (frames count presents per process, from 0).
struct PresentRecord {
  uint64_t queue = 0;
  uint64_t frame = 0;
  std::vector<uint64_t> waitSemaphores;  // binary: the presentation engine consumes their signals
  std::vector<uint64_t> swapchains;
  std::vector<uint32_t> imageIndices;
  int32_t result = 0;
};

// vkAcquireNextImageKHR / vkAcquireNextImage2KHR: a successful one is the presentation
// engine's signal of `semaphore` and `fence` (replay's wait on the semaphore is then satisfied).
struct AcquireRecord {
  uint64_t swapchain = 0;
  uint64_t timeout = 0;
  uint64_t semaphore = 0;
  uint64_t fence = 0;
  uint32_t imageIndex = 0;
  int32_t result = 0;
  uint32_t deviceMask = 0;  // vkAcquireNextImage2KHR only
};

// A host call that synchronizes with the device: replay needs them to know which submissions
// had completed when the host next wrote memory (FenceWait) or what the host signalled.
struct HostSyncRecord {
  enum class Kind {
    EventSet, EventReset, EventStatus,     // vkSetEvent / vkResetEvent / vkGetEventStatus
    FenceWait, FenceReset, FenceStatus,    // vkWaitForFences / vkResetFences / vkGetFenceStatus
    QueueWaitIdle, DeviceWaitIdle,
    SemaphoreSignal, SemaphoreWait,        // vkSignalSemaphore / vkWaitSemaphores
  };
  Kind kind = Kind::FenceWait;
  std::vector<uint64_t> handles;  // events, fences, semaphores, or the queue of QueueWaitIdle
  std::vector<uint64_t> values;   // timeline values of SemaphoreSignal/SemaphoreWait
  bool waitAll = true;            // FenceWait waitAll; SemaphoreWait without VK_SEMAPHORE_WAIT_ANY_BIT
  uint64_t timeout = 0;
  int32_t result = 0;             // the call's VkResult (EventStatus: VK_EVENT_SET/VK_EVENT_RESET)
};

// Everything one vkCmdBuildClusterAccelerationStructureIndirectNV read, as it was when the
// command executed on the queue, and everything it wrote, read after it completed.
// Timestamps: not a command but the readback of one command buffer's timestamps (ticks below).
enum class CapturedCommandKind { ClusterBuild, BuildAccelerationStructureNV, CopyMemoryToAccelerationStructure, Timestamps };

struct ClusterBuildCapture {
  CapturedCommandKind kind = CapturedCommandKind::ClusterBuild;  // parameters apply to ClusterBuild only
  uint64_t pauseId = 0;
  uint32_t occurrence = 0;  // nth execution of this command in its submission (simultaneous use)
  uint64_t submissionIndex = 0;
  uint64_t commandBuffer = 0;
  ClusterCommandParameters parameters;
  uint32_t executedCount = 0;  // min(srcInfosCount value, maxAccelerationStructureCount)
  std::vector<CapturedRange> inputs;
  std::vector<CapturedRange> outputs;
  std::vector<CaptureIssue> issues;
  // Serving: the command ran in clastrace's engine (its outputs are what the engine wrote),
  // and what the engine found wrong with it.
  bool executedByEngine = false;
  std::vector<EngineFindingRecord> engineFindings;
  double pauseMilliseconds = 0;  // queue stall the capture caused (both pauses)
  // Timestamps: the ticks of queries 0..n-1 of the command buffer's layer-owned pool, masked
  // to the queue's valid bits; valid false where the driver reported no result.
  std::vector<uint64_t> timestampTicks;
  std::vector<bool> timestampValid;
  // A served build's record leaves the pause worker unfinished: its outputs are still to be
  // walked in the engine's image (which this holds, `heldBytes` of it) and its ranges named by
  // the buffers of its pause. Whoever writes the record calls this first, on its own thread,
  // so the worker is free for the next pause. Empty for every other record. Once it ran, the
  // outputs are views into that image and keep it (still `heldBytes`) until they are freed.
  std::function<void(ClusterBuildCapture&)> complete;
  uint64_t heldBytes = 0;
};

}  // namespace clastrace::capture
