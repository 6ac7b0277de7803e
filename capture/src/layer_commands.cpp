// Command recording: each intercepted command is forwarded, then recorded into the command
// buffer's log. Cluster builds get the pause points described in pause_worker.h.
#include "clastrace/capture/served_build.h"
#include "command_buffer_log.h"
#include "layer_state.h"

#include <optional>

#include <cstring>
#include <map>

namespace clastrace::capture {
namespace {

DeviceState& deviceOf(VkCommandBuffer cb) { return *findDevice(dispatchKey(cb)); }

std::shared_ptr<CommandBufferLog> logOf(DeviceState& d, VkCommandBuffer cb) {
  std::lock_guard lock(d.commandBuffersMutex);
  auto& log = d.commandBuffers[cb];
  if (!log) {
    log = std::make_shared<CommandBufferLog>();
    log->recorded.commandBuffer = handleId(cb);
  }
  return log;
}

void record(VkCommandBuffer cb, RecordedCommand command) {
  DeviceState& d = deviceOf(cb);
  if (!d.sink) return;
  logOf(d, cb)->recorded.commands.push_back(std::move(command));
}

// ---- Lifetime ---------------------------------------------------------------------------

VKAPI_ATTR VkResult VKAPI_CALL BeginCommandBuffer(VkCommandBuffer cb, const VkCommandBufferBeginInfo* pBeginInfo) {
  DeviceState& d = deviceOf(cb);
  auto log = logOf(d, cb);
  clearCommandBufferLog(d, *log);  // begin implicitly resets
  log->recorded.usage = pBeginInfo->flags;
  {
    std::lock_guard lock(d.commandBuffersMutex);
    log->recorded.secondary = d.secondaryCommandBuffers.count(cb) != 0;
  }
  return d.next.BeginCommandBuffer(cb, pBeginInfo);
}

VKAPI_ATTR VkResult VKAPI_CALL EndCommandBuffer(VkCommandBuffer cb) {
  DeviceState& d = deviceOf(cb);
  VkResult result = d.next.EndCommandBuffer(cb);
  if (result == VK_SUCCESS && d.sink) d.sink->commandBufferRecorded(logOf(d, cb)->recorded);
  return result;
}

VKAPI_ATTR VkResult VKAPI_CALL ResetCommandBuffer(VkCommandBuffer cb, VkCommandBufferResetFlags flags) {
  DeviceState& d = deviceOf(cb);
  VkResult result = d.next.ResetCommandBuffer(cb, flags);
  if (result == VK_SUCCESS) {
    clearCommandBufferLog(d, *logOf(d, cb));
    if (d.sink) d.sink->commandBufferReset(handleId(cb));
  }
  return result;
}

VKAPI_ATTR VkResult VKAPI_CALL AllocateCommandBuffers(VkDevice device, const VkCommandBufferAllocateInfo* pInfo,
                                                      VkCommandBuffer* pCommandBuffers) {
  DeviceState& d = *findDevice(dispatchKey(device));
  VkResult result = d.next.AllocateCommandBuffers(device, pInfo, pCommandBuffers);
  if (result != VK_SUCCESS) return result;
  std::lock_guard lock(d.commandBuffersMutex);
  auto& owned = d.poolCommandBuffers[pInfo->commandPool];
  owned.insert(owned.end(), pCommandBuffers, pCommandBuffers + pInfo->commandBufferCount);
  if (pInfo->level == VK_COMMAND_BUFFER_LEVEL_SECONDARY)
    d.secondaryCommandBuffers.insert(pCommandBuffers, pCommandBuffers + pInfo->commandBufferCount);
  return result;
}

void forgetCommandBuffers(DeviceState& d, VkCommandPool pool, const VkCommandBuffer* list, uint32_t count) {
  std::lock_guard lock(d.commandBuffersMutex);
  for (uint32_t i = 0; i < count; ++i) {
    if (!list[i]) continue;
    auto it = d.commandBuffers.find(list[i]);
    if (it != d.commandBuffers.end()) {
      releaseCommandBufferLog(d, *it->second);
      d.commandBuffers.erase(it);
    }
    d.secondaryCommandBuffers.erase(list[i]);
    auto& owned = d.poolCommandBuffers[pool];
    owned.erase(std::remove(owned.begin(), owned.end(), list[i]), owned.end());
  }
}

VKAPI_ATTR void VKAPI_CALL FreeCommandBuffers(VkDevice device, VkCommandPool pool, uint32_t count,
                                              const VkCommandBuffer* pCommandBuffers) {
  DeviceState& d = *findDevice(dispatchKey(device));
  forgetCommandBuffers(d, pool, pCommandBuffers, count);
  d.next.FreeCommandBuffers(device, pool, count, pCommandBuffers);
}

VKAPI_ATTR VkResult VKAPI_CALL ResetCommandPool(VkDevice device, VkCommandPool pool, VkCommandPoolResetFlags flags) {
  DeviceState& d = *findDevice(dispatchKey(device));
  VkResult result = d.next.ResetCommandPool(device, pool, flags);
  if (result != VK_SUCCESS) return result;
  std::lock_guard lock(d.commandBuffersMutex);
  for (VkCommandBuffer cb : d.poolCommandBuffers[pool]) {
    auto it = d.commandBuffers.find(cb);
    if (it == d.commandBuffers.end()) continue;
    clearCommandBufferLog(d, *it->second);
    if (d.sink) d.sink->commandBufferReset(handleId(cb));
  }
  return result;
}

VKAPI_ATTR void VKAPI_CALL DestroyCommandPool(VkDevice device, VkCommandPool pool, const VkAllocationCallbacks* pAllocator) {
  DeviceState& d = *findDevice(dispatchKey(device));
  std::vector<VkCommandBuffer> owned;
  {
    std::lock_guard lock(d.commandBuffersMutex);
    owned = d.poolCommandBuffers[pool];
  }
  forgetCommandBuffers(d, pool, owned.data(), uint32_t(owned.size()));
  {
    std::lock_guard lock(d.commandBuffersMutex);
    d.poolCommandBuffers.erase(pool);
  }
  d.next.DestroyCommandPool(device, pool, pAllocator);
}

// ---- Synchronization --------------------------------------------------------------------

void copyBarriers1(uint64_t srcStage, uint64_t dstStage, uint32_t memoryCount, const VkMemoryBarrier* memory,
                   uint32_t bufferCount, const VkBufferMemoryBarrier* buffers, std::vector<MemoryBarrier>& outMemory,
                   std::vector<BufferBarrier>& outBuffers) {
  for (uint32_t i = 0; i < memoryCount; ++i)
    outMemory.push_back({srcStage, memory[i].srcAccessMask, dstStage, memory[i].dstAccessMask});
  for (uint32_t i = 0; i < bufferCount; ++i)
    outBuffers.push_back({srcStage, buffers[i].srcAccessMask, dstStage, buffers[i].dstAccessMask,
                          handleId(buffers[i].buffer), buffers[i].offset, buffers[i].size});
}

void copyDependency(const VkDependencyInfo& info, std::vector<MemoryBarrier>& outMemory,
                    std::vector<BufferBarrier>& outBuffers, uint32_t& imageCount) {
  for (uint32_t i = 0; i < info.memoryBarrierCount; ++i) {
    const auto& b = info.pMemoryBarriers[i];
    outMemory.push_back({b.srcStageMask, b.srcAccessMask, b.dstStageMask, b.dstAccessMask});
  }
  for (uint32_t i = 0; i < info.bufferMemoryBarrierCount; ++i) {
    const auto& b = info.pBufferMemoryBarriers[i];
    outBuffers.push_back({b.srcStageMask, b.srcAccessMask, b.dstStageMask, b.dstAccessMask, handleId(b.buffer),
                          b.offset, b.size});
  }
  imageCount += info.imageMemoryBarrierCount;
}

VKAPI_ATTR void VKAPI_CALL CmdPipelineBarrier(VkCommandBuffer cb, VkPipelineStageFlags srcStageMask,
                                              VkPipelineStageFlags dstStageMask, VkDependencyFlags dependencyFlags,
                                              uint32_t memoryBarrierCount, const VkMemoryBarrier* pMemoryBarriers,
                                              uint32_t bufferMemoryBarrierCount,
                                              const VkBufferMemoryBarrier* pBufferMemoryBarriers,
                                              uint32_t imageMemoryBarrierCount,
                                              const VkImageMemoryBarrier* pImageMemoryBarriers) {
  deviceOf(cb).next.CmdPipelineBarrier(cb, srcStageMask, dstStageMask, dependencyFlags, memoryBarrierCount,
                                       pMemoryBarriers, bufferMemoryBarrierCount, pBufferMemoryBarriers,
                                       imageMemoryBarrierCount, pImageMemoryBarriers);
  BarrierCommand c;
  c.srcStageMask = srcStageMask;
  c.dstStageMask = dstStageMask;
  c.dependencyFlags = dependencyFlags;
  copyBarriers1(srcStageMask, dstStageMask, memoryBarrierCount, pMemoryBarriers, bufferMemoryBarrierCount,
                pBufferMemoryBarriers, c.memoryBarriers, c.bufferBarriers);
  c.imageBarrierCount = imageMemoryBarrierCount;
  record(cb, std::move(c));
}

void pipelineBarrier2(VkCommandBuffer cb, const VkDependencyInfo* info, PFN_vkCmdPipelineBarrier2 next) {
  next(cb, info);
  BarrierCommand c;
  c.synchronization2 = true;
  c.dependencyFlags = info->dependencyFlags;
  copyDependency(*info, c.memoryBarriers, c.bufferBarriers, c.imageBarrierCount);
  record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdPipelineBarrier2(VkCommandBuffer cb, const VkDependencyInfo* info) {
  pipelineBarrier2(cb, info, deviceOf(cb).next.CmdPipelineBarrier2);
}
VKAPI_ATTR void VKAPI_CALL CmdPipelineBarrier2KHR(VkCommandBuffer cb, const VkDependencyInfo* info) {
  pipelineBarrier2(cb, info, deviceOf(cb).next.CmdPipelineBarrier2KHR);
}

VKAPI_ATTR void VKAPI_CALL CmdSetEvent(VkCommandBuffer cb, VkEvent event, VkPipelineStageFlags stageMask) {
  deviceOf(cb).next.CmdSetEvent(cb, event, stageMask);
  EventCommand c;
  c.kind = EventCommand::Kind::Set;
  c.events = {handleId(event)};
  c.srcStageMask = stageMask;
  record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdResetEvent(VkCommandBuffer cb, VkEvent event, VkPipelineStageFlags stageMask) {
  deviceOf(cb).next.CmdResetEvent(cb, event, stageMask);
  EventCommand c;
  c.kind = EventCommand::Kind::Reset;
  c.events = {handleId(event)};
  c.srcStageMask = stageMask;
  record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdWaitEvents(VkCommandBuffer cb, uint32_t eventCount, const VkEvent* pEvents,
                                         VkPipelineStageFlags srcStageMask, VkPipelineStageFlags dstStageMask,
                                         uint32_t memoryBarrierCount, const VkMemoryBarrier* pMemoryBarriers,
                                         uint32_t bufferMemoryBarrierCount,
                                         const VkBufferMemoryBarrier* pBufferMemoryBarriers,
                                         uint32_t imageMemoryBarrierCount,
                                         const VkImageMemoryBarrier* pImageMemoryBarriers) {
  deviceOf(cb).next.CmdWaitEvents(cb, eventCount, pEvents, srcStageMask, dstStageMask, memoryBarrierCount,
                                  pMemoryBarriers, bufferMemoryBarrierCount, pBufferMemoryBarriers,
                                  imageMemoryBarrierCount, pImageMemoryBarriers);
  EventCommand c;
  c.kind = EventCommand::Kind::Wait;
  for (uint32_t i = 0; i < eventCount; ++i) c.events.push_back(handleId(pEvents[i]));
  c.srcStageMask = srcStageMask;
  c.dstStageMask = dstStageMask;
  copyBarriers1(srcStageMask, dstStageMask, memoryBarrierCount, pMemoryBarriers, bufferMemoryBarrierCount,
                pBufferMemoryBarriers, c.memoryBarriers, c.bufferBarriers);
  record(cb, std::move(c));
}

void setEvent2(VkCommandBuffer cb, VkEvent event, const VkDependencyInfo* info, PFN_vkCmdSetEvent2 next) {
  next(cb, event, info);
  EventCommand c;
  c.kind = EventCommand::Kind::Set;
  c.synchronization2 = true;
  c.events = {handleId(event)};
  uint32_t images = 0;
  copyDependency(*info, c.memoryBarriers, c.bufferBarriers, images);
  record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdSetEvent2(VkCommandBuffer cb, VkEvent e, const VkDependencyInfo* i) {
  setEvent2(cb, e, i, deviceOf(cb).next.CmdSetEvent2);
}
VKAPI_ATTR void VKAPI_CALL CmdSetEvent2KHR(VkCommandBuffer cb, VkEvent e, const VkDependencyInfo* i) {
  setEvent2(cb, e, i, deviceOf(cb).next.CmdSetEvent2KHR);
}
void resetEvent2(VkCommandBuffer cb, VkEvent event, VkPipelineStageFlags2 stageMask, PFN_vkCmdResetEvent2 next) {
  next(cb, event, stageMask);
  EventCommand c;
  c.kind = EventCommand::Kind::Reset;
  c.synchronization2 = true;
  c.events = {handleId(event)};
  c.srcStageMask = stageMask;
  record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdResetEvent2(VkCommandBuffer cb, VkEvent e, VkPipelineStageFlags2 s) {
  resetEvent2(cb, e, s, deviceOf(cb).next.CmdResetEvent2);
}
VKAPI_ATTR void VKAPI_CALL CmdResetEvent2KHR(VkCommandBuffer cb, VkEvent e, VkPipelineStageFlags2 s) {
  resetEvent2(cb, e, s, deviceOf(cb).next.CmdResetEvent2KHR);
}
void waitEvents2(VkCommandBuffer cb, uint32_t count, const VkEvent* events, const VkDependencyInfo* infos,
                 PFN_vkCmdWaitEvents2 next) {
  next(cb, count, events, infos);
  EventCommand c;
  c.kind = EventCommand::Kind::Wait;
  c.synchronization2 = true;
  uint32_t images = 0;
  for (uint32_t i = 0; i < count; ++i) {
    c.events.push_back(handleId(events[i]));
    copyDependency(infos[i], c.memoryBarriers, c.bufferBarriers, images);
  }
  record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdWaitEvents2(VkCommandBuffer cb, uint32_t n, const VkEvent* e, const VkDependencyInfo* i) {
  waitEvents2(cb, n, e, i, deviceOf(cb).next.CmdWaitEvents2);
}
VKAPI_ATTR void VKAPI_CALL CmdWaitEvents2KHR(VkCommandBuffer cb, uint32_t n, const VkEvent* e, const VkDependencyInfo* i) {
  waitEvents2(cb, n, e, i, deviceOf(cb).next.CmdWaitEvents2KHR);
}

// ---- Transfers and dispatches ---------------------------------------------------------------

VKAPI_ATTR void VKAPI_CALL CmdCopyBuffer(VkCommandBuffer cb, VkBuffer src, VkBuffer dst, uint32_t regionCount,
                                         const VkBufferCopy* pRegions) {
  deviceOf(cb).next.CmdCopyBuffer(cb, src, dst, regionCount, pRegions);
  record(cb, CopyBufferCommand{handleId(src), handleId(dst), {pRegions, pRegions + regionCount}});
}
void copyBuffer2(VkCommandBuffer cb, const VkCopyBufferInfo2* info, PFN_vkCmdCopyBuffer2 next) {
  next(cb, info);
  CopyBufferCommand c{handleId(info->srcBuffer), handleId(info->dstBuffer), {}};
  for (uint32_t i = 0; i < info->regionCount; ++i)
    c.regions.push_back({info->pRegions[i].srcOffset, info->pRegions[i].dstOffset, info->pRegions[i].size});
  record(cb, std::move(c));
}
VKAPI_ATTR void VKAPI_CALL CmdCopyBuffer2(VkCommandBuffer cb, const VkCopyBufferInfo2* info) {
  copyBuffer2(cb, info, deviceOf(cb).next.CmdCopyBuffer2);
}
VKAPI_ATTR void VKAPI_CALL CmdCopyBuffer2KHR(VkCommandBuffer cb, const VkCopyBufferInfo2* info) {
  copyBuffer2(cb, info, deviceOf(cb).next.CmdCopyBuffer2KHR);
}
VKAPI_ATTR void VKAPI_CALL CmdFillBuffer(VkCommandBuffer cb, VkBuffer dst, VkDeviceSize offset, VkDeviceSize size,
                                         uint32_t data) {
  deviceOf(cb).next.CmdFillBuffer(cb, dst, offset, size, data);
  record(cb, FillBufferCommand{handleId(dst), offset, size, data});
}
VKAPI_ATTR void VKAPI_CALL CmdUpdateBuffer(VkCommandBuffer cb, VkBuffer dst, VkDeviceSize offset, VkDeviceSize size,
                                           const void* pData) {
  deviceOf(cb).next.CmdUpdateBuffer(cb, dst, offset, size, pData);
  auto* bytes = static_cast<const uint8_t*>(pData);
  record(cb, UpdateBufferCommand{handleId(dst), offset, {bytes, bytes + size}});
}
// ---- Compute state: which storage buffers a dispatch sees ----------------------------------

VKAPI_ATTR void VKAPI_CALL UpdateDescriptorSets(VkDevice device, uint32_t writeCount, const VkWriteDescriptorSet* writes,
                                                uint32_t copyCount, const VkCopyDescriptorSet* copies) {
  DeviceState& d = *findDevice(dispatchKey(device));
  d.next.UpdateDescriptorSets(device, writeCount, writes, copyCount, copies);
  std::lock_guard lock(d.descriptorsMutex);
  for (uint32_t w = 0; w < writeCount; ++w) {
    const VkWriteDescriptorSet& write = writes[w];
    const bool storage = write.descriptorType == VK_DESCRIPTOR_TYPE_STORAGE_BUFFER ||
                         write.descriptorType == VK_DESCRIPTOR_TYPE_STORAGE_BUFFER_DYNAMIC;
    auto& set = d.storageDescriptors[write.dstSet];
    // Consecutive descriptors continue at element + i of the same binding (overflow into the
    // next binding is not followed).
    for (uint32_t i = 0; i < write.descriptorCount; ++i) {
      const std::pair<uint32_t, uint32_t> key{write.dstBinding, write.dstArrayElement + i};
      if (!storage || !write.pBufferInfo) {
        set.erase(key);
        continue;
      }
      const VkDescriptorBufferInfo& info = write.pBufferInfo[i];
      BoundStorageBuffer b;
      b.binding = write.dstBinding;
      b.arrayElement = write.dstArrayElement + i;
      b.type = write.descriptorType;
      b.buffer = handleId(info.buffer);
      b.offset = info.offset;
      b.range = info.range;
      set[key] = b;
    }
  }
  for (uint32_t c = 0; c < copyCount; ++c) {
    const VkCopyDescriptorSet& copy = copies[c];
    auto source = d.storageDescriptors.find(copy.srcSet);
    for (uint32_t i = 0; i < copy.descriptorCount; ++i) {
      const std::pair<uint32_t, uint32_t> to{copy.dstBinding, copy.dstArrayElement + i};
      auto& dst = d.storageDescriptors[copy.dstSet];
      if (source == d.storageDescriptors.end()) {
        dst.erase(to);
        continue;
      }
      auto from = source->second.find({copy.srcBinding, copy.srcArrayElement + i});
      if (from == source->second.end()) {
        dst.erase(to);
        continue;
      }
      BoundStorageBuffer b = from->second;
      b.binding = to.first;
      b.arrayElement = to.second;
      dst[to] = b;
    }
  }
}

VKAPI_ATTR void VKAPI_CALL CmdBindPipeline(VkCommandBuffer cb, VkPipelineBindPoint bindPoint, VkPipeline pipeline) {
  DeviceState& d = deviceOf(cb);
  d.next.CmdBindPipeline(cb, bindPoint, pipeline);
  if (bindPoint == VK_PIPELINE_BIND_POINT_COMPUTE) logOf(d, cb)->computePipeline = handleId(pipeline);
}

VKAPI_ATTR void VKAPI_CALL CmdBindDescriptorSets(VkCommandBuffer cb, VkPipelineBindPoint bindPoint,
                                                 VkPipelineLayout layout, uint32_t firstSet, uint32_t setCount,
                                                 const VkDescriptorSet* sets, uint32_t dynamicOffsetCount,
                                                 const uint32_t* dynamicOffsets) {
  DeviceState& d = deviceOf(cb);
  d.next.CmdBindDescriptorSets(cb, bindPoint, layout, firstSet, setCount, sets, dynamicOffsetCount, dynamicOffsets);
  if (bindPoint != VK_PIPELINE_BIND_POINT_COMPUTE) return;
  auto log = logOf(d, cb);
  // Dynamic offsets are consumed set by set, in binding order, by every dynamic descriptor;
  // the layer knows only the storage ones, so with dynamic uniform buffers in the same set
  // the split is approximate (see README).
  uint32_t nextOffset = 0;
  std::lock_guard lock(d.descriptorsMutex);
  for (uint32_t s = 0; s < setCount; ++s) {
    std::vector<uint32_t> offsets;
    auto known = d.storageDescriptors.find(sets[s]);
    if (known != d.storageDescriptors.end())
      for (const auto& [key, b] : known->second)
        if (b.type == VK_DESCRIPTOR_TYPE_STORAGE_BUFFER_DYNAMIC && nextOffset < dynamicOffsetCount)
          offsets.push_back(dynamicOffsets[nextOffset++]);
    log->computeSets[firstSet + s] = {sets[s], offsets};
  }
}

std::vector<BoundStorageBuffer> boundStorageBuffers(DeviceState& d, const CommandBufferLog& log) {
  std::vector<BoundStorageBuffer> out;
  std::lock_guard lock(d.descriptorsMutex);
  for (const auto& [setIndex, bound] : log.computeSets) {
    auto known = d.storageDescriptors.find(bound.first);
    if (known == d.storageDescriptors.end()) continue;
    size_t dynamic = 0;
    for (const auto& [key, descriptor] : known->second) {
      BoundStorageBuffer b = descriptor;
      b.set = setIndex;
      if (b.type == VK_DESCRIPTOR_TYPE_STORAGE_BUFFER_DYNAMIC && dynamic < bound.second.size())
        b.offset += bound.second[dynamic++];
      if (auto buffer = d.memoryMap.buffer(b.buffer); buffer && buffer->address) b.address = buffer->address + b.offset;
      out.push_back(b);
    }
  }
  return out;
}

VKAPI_ATTR void VKAPI_CALL CmdDispatch(VkCommandBuffer cb, uint32_t x, uint32_t y, uint32_t z) {
  DeviceState& d = deviceOf(cb);
  d.next.CmdDispatch(cb, x, y, z);
  if (!d.sink) return;
  auto log = logOf(d, cb);
  DispatchCommand c{x, y, z, log->computePipeline, 0, 0, boundStorageBuffers(d, *log)};
  log->recorded.commands.push_back(std::move(c));
}

VKAPI_ATTR void VKAPI_CALL CmdDispatchIndirect(VkCommandBuffer cb, VkBuffer buffer, VkDeviceSize offset) {
  DeviceState& d = deviceOf(cb);
  d.next.CmdDispatchIndirect(cb, buffer, offset);
  if (!d.sink) return;
  auto log = logOf(d, cb);
  DispatchCommand c{0, 0, 0, log->computePipeline, handleId(buffer), offset, boundStorageBuffers(d, *log)};
  log->recorded.commands.push_back(std::move(c));
}

VKAPI_ATTR void VKAPI_CALL CmdExecuteCommands(VkCommandBuffer cb, uint32_t count, const VkCommandBuffer* secondaries) {
  DeviceState& d = deviceOf(cb);
  d.next.CmdExecuteCommands(cb, count, secondaries);
  // The secondaries' pauses happen when this primary runs: the worker must expect them here,
  // in execution order (a secondary listed twice pauses twice).
  auto primary = logOf(d, cb);
  ExecuteCommandsCommand c;
  for (uint32_t i = 0; i < count; ++i) {
    auto secondary = logOf(d, secondaries[i]);
    const size_t first = primary->pauses.size();
    primary->pauses.insert(primary->pauses.end(), secondary->pauses.begin(), secondary->pauses.end());
    // A simultaneous-use secondary may run inside primaries on two queues at once.
    if (secondary->recorded.usage & VK_COMMAND_BUFFER_USAGE_SIMULTANEOUS_USE_BIT)
      for (size_t p = first; p < primary->pauses.size(); ++p) primary->pauses[p].shared = true;
    c.secondaries.push_back(handleId(secondaries[i]));
  }
  if (d.sink) primary->recorded.commands.push_back(std::move(c));
}

// ---- The captured commands ------------------------------------------------------------------

// Records barrier + set(signal) + wait(release) + reset(release); see pause_worker.h.
void recordPause(DeviceState& d, VkCommandBuffer cb, CommandBufferLog& log, PausePoint pause) {
  VkEventCreateInfo eventInfo{VK_STRUCTURE_TYPE_EVENT_CREATE_INFO, nullptr, 0};
  auto event = [&](VkEvent* out) {
    if (log.spareEvents.empty()) return d.next.CreateEvent(d.device, &eventInfo, nullptr, out) == VK_SUCCESS;
    *out = log.spareEvents.back();
    log.spareEvents.pop_back();
    return true;
  };
  // Spares lie in (signal, release) pairs: each event keeps its role (validation tracks which
  // stage last set an event, and a wait names that stage).
  if (!event(&pause.release)) return;
  if (!event(&pause.signal)) {
    log.spareEvents.push_back(pause.release);
    return;
  }
  log.events.push_back(pause.signal);
  log.events.push_back(pause.release);
  std::shared_ptr<StagingSet> staging = createStaging(d);
  if (staging) {
    log.staging.push_back(staging);
    pause.staging = staging;
    recordCopiesToStaging(d, cb, *staging);
  }

  const VkMemoryBarrier toHost{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_MEMORY_WRITE_BIT,
                               VK_ACCESS_HOST_READ_BIT | VK_ACCESS_MEMORY_READ_BIT};
  d.next.CmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                            VK_PIPELINE_STAGE_ALL_COMMANDS_BIT | VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &toHost, 0, nullptr,
                            0, nullptr);
  d.next.CmdSetEvent(cb, pause.signal, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT);
  const VkMemoryBarrier fromHost{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_HOST_WRITE_BIT,
                                 VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT};
  d.next.CmdWaitEvents(cb, 1, &pause.release, VK_PIPELINE_STAGE_HOST_BIT, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, 1,
                       &fromHost, 0, nullptr, 0, nullptr);
  d.next.CmdResetEvent(cb, pause.release, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT);
  // A served build wrote its outputs into the staged copies.
  if (staging && d.serving && pause.parameters && pause.phase == PausePhase::BeforeCommand)
    recordCopiesFromStaging(d, cb, *staging);
  log.pauses.push_back(std::move(pause));
}

// Queries per recording: a pair per captured command. Commands past the first 128 of one
// recording get no timestamps (the analyzer simply sees no span for them).
constexpr uint32_t kTimestampQueries = 256;

// Writes a timestamp of the layer's own pool into `cb` and returns its record (the caller puts
// it in the log around the command's record), or nothing when timestamps are off, the command
// buffer is secondary (its pauses run inside a primary; not supported), or the pool is full.
// `pairStart`: the first of a pair, written only when its partner fits too.
std::optional<TimestampWriteCommand> writeTimestamp(DeviceState& d, VkCommandBuffer cb, CommandBufferLog& log,
                                                    VkPipelineStageFlagBits stage, bool pairStart) {
  if (!d.timestamps || !d.capturingNow() || log.recorded.secondary) return std::nullopt;
  if (log.timestampsWritten + (pairStart ? 2 : 1) > kTimestampQueries) return std::nullopt;
  if (!log.timestampPool && log.spareTimestampPool) {
    log.timestampPool = log.spareTimestampPool;
    log.spareTimestampPool = VK_NULL_HANDLE;
    d.next.CmdResetQueryPool(cb, log.timestampPool, 0, kTimestampQueries);
    log.timestampReadPauseId = ++d.pauseCounter;
  }
  if (!log.timestampPool) {
    VkQueryPoolCreateInfo info{};
    info.sType = VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO;
    info.queryType = VK_QUERY_TYPE_TIMESTAMP;
    info.queryCount = kTimestampQueries;
    if (d.next.CreateQueryPool(d.device, &info, nullptr, &log.timestampPool) != VK_SUCCESS) {
      log.timestampPool = VK_NULL_HANDLE;
      log.timestampsWritten = kTimestampQueries;  // do not try again in this recording
      return std::nullopt;
    }
    // Reset in the command buffer, so each execution starts from unavailable queries.
    d.next.CmdResetQueryPool(cb, log.timestampPool, 0, kTimestampQueries);
    log.timestampReadPauseId = ++d.pauseCounter;
  }
  const uint32_t query = log.timestampsWritten++;
  d.next.CmdWriteTimestamp(cb, stage, log.timestampPool, query);
  return TimestampWriteCommand{handleId(log.timestampPool), query, uint64_t(stage), log.timestampReadPauseId};
}

// Start: once everything before (the pause's wait included) has finished, so the span is the
// command's alone. End: once the command has finished.
std::optional<TimestampWriteCommand> timestampBefore(DeviceState& d, VkCommandBuffer cb, CommandBufferLog& log) {
  auto t = writeTimestamp(d, cb, log, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, true);
  if (t) log.recorded.commands.push_back(*t);
  return t;
}
std::optional<TimestampWriteCommand> timestampAfter(DeviceState& d, VkCommandBuffer cb, CommandBufferLog& log,
                                                    bool started) {
  if (!started) return std::nullopt;
  return writeTimestamp(d, cb, log, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, false);
}

VKAPI_ATTR void VKAPI_CALL CmdBuildClusterAccelerationStructureIndirectNV(
    VkCommandBuffer cb, const VkClusterAccelerationStructureCommandsInfoNV* pCommandInfos) {
  DeviceState& d = deviceOf(cb);
  auto parameters = std::make_shared<const ClusterCommandParameters>(ClusterCommandParameters::copyOf(*pCommandInfos));
  const uint64_t pauseId = ++d.pauseCounter;
  auto log = logOf(d, cb);
  // Capture needs a pause before (inputs) and after (outputs); serving needs the one before,
  // where the build runs while the queue waits.
  // When serving, the command is the engine's run at the pause before it, and the queue does
  // nothing until the next command: the outputs are read in that same pause.
  const bool pauseAfter = d.capturingNow() && !d.serving;
  // Served, the command's execution is the engine's run inside the pause before it: its span
  // covers that pause (the queue's time on the command, capture reading included). Native, the
  // span starts after the pause, so the capture's stall is not counted.
  bool started = d.serving && timestampBefore(d, cb, *log).has_value();
  if (d.capturingNow() || d.serving) {
    PausePoint before;
    before.pauseId = pauseId;
    before.phase = PausePhase::BeforeCommand;
    before.lastOfCommand = !pauseAfter;
    before.parameters = parameters;
    recordPause(d, cb, *log, before);
  }
  if (!d.serving) started = timestampBefore(d, cb, *log).has_value();
  if (!d.serving && d.next.CmdBuildClusterAccelerationStructureIndirectNV)
    d.next.CmdBuildClusterAccelerationStructureIndirectNV(cb, pCommandInfos);
  auto ended = timestampAfter(d, cb, *log, started);
  if (pauseAfter) {
    PausePoint after;
    after.pauseId = pauseId;
    after.phase = PausePhase::AfterCommand;
    after.lastOfCommand = true;
    after.parameters = parameters;
    recordPause(d, cb, *log, after);
  }
  if (d.sink) log->recorded.commands.push_back(ClusterBuildCommand{*parameters, pauseId, d.serving});
  if (ended) log->recorded.commands.push_back(*ended);
}

VKAPI_ATTR void VKAPI_CALL GetClusterAccelerationStructureBuildSizesNV(VkDevice device,
                                                                       const VkClusterAccelerationStructureInputInfoNV* pInfo,
                                                                       VkAccelerationStructureBuildSizesInfoKHR* pSizeInfo) {
  DeviceState& d = *findDevice(dispatchKey(device));
  BuildSizesQuery query;
  if (d.serving || !d.next.GetClusterAccelerationStructureBuildSizesNV) {
    servedClusterBuildSizes(*pInfo, *pSizeInfo);
    query.answeredByLayer = true;
  } else {
    d.next.GetClusterAccelerationStructureBuildSizesNV(device, pInfo, pSizeInfo);
  }
  if (!d.sink) return;
  query.device = handleId(device);
  query.input = copyClusterInput(*pInfo);
  query.answer = *pSizeInfo;
  query.answer.pNext = nullptr;
  d.sink->buildSizesQueried(query);
}

VKAPI_ATTR void VKAPI_CALL CmdBuildAccelerationStructureNV(VkCommandBuffer cb, const VkAccelerationStructureInfoNV* pInfo,
                                                           VkBuffer instanceData, VkDeviceSize instanceOffset,
                                                           VkBool32 update, VkAccelerationStructureNV dst,
                                                           VkAccelerationStructureNV src, VkBuffer scratch,
                                                           VkDeviceSize scratchOffset) {
  DeviceState& d = deviceOf(cb);
  auto c = std::make_shared<BuildAccelerationStructureNVCommand>();
  c->type = pInfo->type;
  c->flags = pInfo->flags;
  c->instanceCount = pInfo->instanceCount;
  for (uint32_t i = 0; i < pInfo->geometryCount; ++i) {
    VkGeometryNV g = pInfo->pGeometries[i];
    g.pNext = nullptr;
    g.geometry.triangles.pNext = nullptr;
    g.geometry.aabbs.pNext = nullptr;
    c->geometries.push_back(g);
  }
  c->instanceData = handleId(instanceData);
  c->instanceOffset = instanceOffset;
  c->update = update;
  c->dst = handleId(dst);
  c->src = handleId(src);
  c->scratch = handleId(scratch);
  c->scratchOffset = scratchOffset;
  auto log = logOf(d, cb);
  if (d.capturingNow()) {  // inputs only: the NV structure's own memory is opaque to the layer
    c->pauseId = ++d.pauseCounter;
    PausePoint before;
    before.pauseId = c->pauseId;
    before.buildNV = c;
    recordPause(d, cb, *log, before);
  }
  const bool started = timestampBefore(d, cb, *log).has_value();
  d.next.CmdBuildAccelerationStructureNV(cb, pInfo, instanceData, instanceOffset, update, dst, src, scratch,
                                         scratchOffset);
  auto ended = timestampAfter(d, cb, *log, started);
  if (d.sink) log->recorded.commands.push_back(*c);
  if (ended) log->recorded.commands.push_back(*ended);
}

VKAPI_ATTR void VKAPI_CALL CmdCopyMemoryToAccelerationStructureKHR(VkCommandBuffer cb,
                                                                   const VkCopyMemoryToAccelerationStructureInfoKHR* pInfo) {
  DeviceState& d = deviceOf(cb);
  auto c = std::make_shared<CopyMemoryToAccelerationStructureCommand>();
  c->src = pInfo->src.deviceAddress;
  c->dst = handleId(pInfo->dst);
  c->mode = pInfo->mode;
  auto log = logOf(d, cb);
  if (d.capturingNow()) {
    c->pauseId = ++d.pauseCounter;
    PausePoint before;
    before.pauseId = c->pauseId;
    before.copyToAccelerationStructure = c;
    recordPause(d, cb, *log, before);
  }
  const bool started = timestampBefore(d, cb, *log).has_value();
  d.next.CmdCopyMemoryToAccelerationStructureKHR(cb, pInfo);
  auto ended = timestampAfter(d, cb, *log, started);
  if (d.sink) log->recorded.commands.push_back(*c);
  if (ended) log->recorded.commands.push_back(*ended);
}

}  // namespace

void clearCommandBufferLog(DeviceState& d, CommandBufferLog& log) {
  if (d.pauses) d.pauses->forgetEvents(log.events);
  // No execution is pending (the command buffer is re-begun, reset or freed): an abandoned
  // pause may have left an event set, so each starts over unsignalled.
  for (VkEvent event : log.events) {
    d.next.ResetEvent(d.device, event);
    log.spareEvents.push_back(event);
  }
  log.events.clear();
  for (auto& staging : log.staging) destroyStaging(d, *staging);
  log.staging.clear();
  log.pauses.clear();
  if (log.timestampPool) {
    // Resetting, freeing or re-beginning is allowed only once no execution is pending: what was
    // not read yet is final now.
    const VkQueryPool pool = log.timestampPool;
    readCompletedTimestamps(d, [pool](const DeviceState::PendingTimestampRead& r) { return r.pool == pool; });
    log.spareTimestampPool = pool;  // the next recording resets it before its first query
  }
  log.timestampPool = VK_NULL_HANDLE;
  log.timestampsWritten = 0;
  log.timestampReadPauseId = 0;
  log.recorded.commands.clear();
  log.computePipeline = 0;
  log.computeSets.clear();
}

void releaseCommandBufferLog(DeviceState& d, CommandBufferLog& log) {
  clearCommandBufferLog(d, log);
  for (VkEvent event : log.spareEvents) d.next.DestroyEvent(d.device, event, nullptr);
  log.spareEvents.clear();
  if (log.spareTimestampPool) d.next.DestroyQueryPool(d.device, log.spareTimestampPool, nullptr);
  log.spareTimestampPool = VK_NULL_HANDLE;
}

PFN_vkVoidFunction commandHook(const char* name) {
#define HOOK(fn) {"vk" #fn, (PFN_vkVoidFunction)fn}
  static const std::map<std::string, PFN_vkVoidFunction, std::less<>> hooks = {
      HOOK(BeginCommandBuffer), HOOK(EndCommandBuffer), HOOK(ResetCommandBuffer), HOOK(AllocateCommandBuffers),
      HOOK(FreeCommandBuffers), HOOK(ResetCommandPool), HOOK(DestroyCommandPool), HOOK(CmdPipelineBarrier),
      HOOK(CmdPipelineBarrier2), HOOK(CmdPipelineBarrier2KHR), HOOK(CmdSetEvent), HOOK(CmdSetEvent2),
      HOOK(CmdSetEvent2KHR), HOOK(CmdResetEvent), HOOK(CmdResetEvent2), HOOK(CmdResetEvent2KHR), HOOK(CmdWaitEvents),
      HOOK(CmdWaitEvents2), HOOK(CmdWaitEvents2KHR), HOOK(CmdCopyBuffer), HOOK(CmdCopyBuffer2), HOOK(CmdCopyBuffer2KHR),
      HOOK(CmdFillBuffer), HOOK(CmdUpdateBuffer), HOOK(CmdDispatch), HOOK(CmdDispatchIndirect),
      HOOK(CmdBindPipeline), HOOK(CmdBindDescriptorSets), HOOK(UpdateDescriptorSets), HOOK(CmdExecuteCommands),
      HOOK(CmdBuildAccelerationStructureNV), HOOK(CmdCopyMemoryToAccelerationStructureKHR),
  };
  auto it = hooks.find(name);
  return it == hooks.end() ? nullptr : it->second;
}

PFN_vkVoidFunction clusterHook(const char* name) {
  if (std::strcmp(name, "vkCmdBuildClusterAccelerationStructureIndirectNV") == 0)
    return (PFN_vkVoidFunction)CmdBuildClusterAccelerationStructureIndirectNV;
  if (std::strcmp(name, "vkGetClusterAccelerationStructureBuildSizesNV") == 0)
    return (PFN_vkVoidFunction)GetClusterAccelerationStructureBuildSizesNV;
  return nullptr;
}

}  // namespace clastrace::capture
