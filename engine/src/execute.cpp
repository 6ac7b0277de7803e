// The command: resolve indirections and the op count, run ops chunk by chunk (reads in
// parallel, writes in op order), then check what only the whole command shows
// (overlaps, totals) and update the object directory.
#include "clastrace/engine/build_sizes.h"
#include "clastrace/engine/execute.h"
#include "execute_internal.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <map>

namespace clastrace::engine {

using detail::hex;
using detail::OpOutput;
using detail::Recorder;
using detail::ResolvedCommand;

namespace {

const char* src_infos_vuid(VkClusterAccelerationStructureOpTypeNV t) {
  switch (t) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV: return "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10448";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV: return "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10449";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV: return "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10450";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV: return "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10451";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV: return "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10452";
    default: return "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10832";
  }
}

uint64_t src_info_size(VkClusterAccelerationStructureOpTypeNV t) {
  switch (t) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV: return sizeof(VkClusterAccelerationStructureMoveObjectsInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV: return sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV: return sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV: return sizeof(VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV);
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV: return sizeof(VkClusterAccelerationStructureInstantiateClusterInfoNV);
    default: return sizeof(VkClusterAccelerationStructureGetTemplateIndicesInfoNV);
  }
}

// How many whole elements of `element` bytes at `stride` fit in `bytes`.
uint64_t elements_in(uint64_t bytes, uint64_t stride, uint64_t element) {
  if (bytes < element) return 0;
  return (bytes - element) / stride + 1;
}

// Keeps at most `cap` findings per rule; counts the rest.
struct FindingSink {
  std::vector<Finding>& out;
  uint32_t cap;
  std::map<std::string, uint64_t> counts;
  void add(Finding f) {
    if (++counts[f.rule] <= cap) out.push_back(std::move(f));
  }
  void close() {
    for (const auto& [rule, n] : counts)
      if (n > cap)
        out.push_back({kRuleFindingsTruncated,
                       std::to_string(n - cap) + " more findings of rule " + rule + " in this command were not kept",
                       -1, 0});
  }
};

struct Written {
  uint64_t begin, end;
  int64_t op;
};

// ExecuteOptions::first_without_usage when the caller has no buffer list: the image's
// regions, each with one usage (0: unknown, taken as allowed); bytes in no region are the
// memory rules' business.
std::optional<uint64_t> first_region_without_usage(const MemoryImage& memory, uint64_t begin, uint64_t end,
                                                   VkBufferUsageFlags bit) {
  const auto& regions = memory.regions();
  auto it = regions.upper_bound(begin);
  if (it != regions.begin()) --it;
  for (; it != regions.end() && it->first < end; ++it) {
    const MemoryRegion& r = it->second;
    if (r.base + r.size <= begin) continue;
    if (r.usage != 0 && !(r.usage & bit)) return std::max(begin, r.base);
  }
  return std::nullopt;
}

}  // namespace

ExecutionRecord execute(const VkClusterAccelerationStructureCommandsInfoNV& command, MemoryImage& memory,
                        const ExecuteOptions& options) {
  ExecutionRecord record;
  const auto& input = command.input;
  record.op_type = input.opType;
  record.op_mode = input.opMode;
  FindingSink sink{record.findings, std::max<uint32_t>(1, options.max_findings_per_rule), {}};
  Recorder top;
  auto finish = [&] {
    for (auto& f : top.findings) sink.add(std::move(f));
    top.findings.clear();
  };

  if (input.opType > VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV) {
    sink.add({"VUID-VkClusterAccelerationStructureInputInfoNV-opType-parameter",
              "input.opType = " + std::to_string(int(input.opType)) + " is not a VkClusterAccelerationStructureOpTypeNV",
              -1, 0});
    return record;
  }
  if (input.opMode > VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV) {
    sink.add({"VUID-VkClusterAccelerationStructureInputInfoNV-opMode-parameter",
              "input.opMode = " + std::to_string(int(input.opMode)) + " is not a VkClusterAccelerationStructureOpModeNV",
              -1, 0});
    return record;
  }
  bool has_input = input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV
                       ? input.opInput.pMoveObjects != nullptr
                   : input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV
                       ? input.opInput.pClustersBottomLevel != nullptr
                       : input.opInput.pTriangleClusters != nullptr;
  if (!has_input) {
    sink.add({kRuleMissingInput, "input.opInput holds a null pointer for opType " + std::to_string(int(input.opType)),
              -1, 0});
    return record;
  }
  const EngineProperties& props = options.properties;
  ObjectDirectory local_directory;
  ObjectDirectory& directory = options.directory ? *options.directory : local_directory;
  const auto mode = input.opMode;
  const bool implicit = mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
  const bool explicit_mode = mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
  const bool sizes_only = mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV;

  if (options.queried_max_count != 0 && input.maxAccelerationStructureCount > options.queried_max_count)
    top.finding("VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10445",
                "input.maxAccelerationStructureCount = " + std::to_string(input.maxAccelerationStructureCount) +
                    " exceeds the " + std::to_string(options.queried_max_count) + " the build sizes were queried with");

  // Address resolution: an indirected field holds the address of the value.
  const auto flags = command.addressResolutionFlags;
  bool resolve_ok = true;
  auto resolve = [&](uint64_t value, uint32_t bit, const char* name) -> uint64_t {
    if (!(flags & bit) || value == 0) return value;
    std::string f = std::string(name) + " (indirected)";
    try {
      uint64_t v = memory.read<uint64_t>(value, {f.c_str(), -1});
      top.access(value, 8, kAccessIndirect, false, f);
      return v;
    } catch (const MemoryFault& fault) {
      top.fault(fault);
      resolve_ok = false;
      return 0;
    }
  };
  ResolvedCommand cmd;
  cmd.op_type = input.opType;
  cmd.op_mode = mode;
  cmd.input = &input;
  cmd.properties = &props;
  cmd.directory = &directory;
  cmd.info_size = src_info_size(input.opType);
  cmd.src_infos = command.srcInfosArray;
  cmd.src_infos.deviceAddress = resolve(command.srcInfosArray.deviceAddress,
                                        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV,
                                        "srcInfosArray");
  cmd.scratch = resolve(command.scratchData, VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SCRATCH_DATA_BIT_NV,
                        "scratchData");
  if (implicit)
    cmd.implicit_data = resolve(command.dstImplicitData,
                                VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_IMPLICIT_DATA_BIT_NV,
                                "dstImplicitData");
  if (!sizes_only) {
    cmd.dst_addresses = command.dstAddressesArray;
    cmd.dst_addresses.deviceAddress = resolve(
        command.dstAddressesArray.deviceAddress,
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV, "dstAddressesArray");
  }
  cmd.dst_sizes = command.dstSizesArray;
  cmd.dst_sizes.deviceAddress = resolve(command.dstSizesArray.deviceAddress,
                                        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV,
                                        "dstSizesArray");
  uint64_t count_address = resolve(command.srcInfosCount,
                                   VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV,
                                   "srcInfosCount");
  record.scratch_address = cmd.scratch;
  if (!resolve_ok) {
    finish();
    record.accesses = std::move(top.accesses);
    return record;
  }

  // Buffer usage (12304-12308), where the trace recorded it (usage 0: unknown, not checked).
  auto check_usage = [&](uint64_t address, VkBufferUsageFlags bit, const char* vuid, const char* what) {
    if (address == 0) return;
    const MemoryRegion* region = memory.find_region(address);
    if (region && region->usage != 0 && !(region->usage & bit))
      top.finding(vuid, std::string(what) + " " + hex(address) + " lies in buffer '" + region->label +
                            "', which was not created with the usage it requires",
                  address);
  };
  check_usage(cmd.scratch, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
              "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12304", "scratchData");
  check_usage(count_address, VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR,
              "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12306", "srcInfosCount");
  check_usage(cmd.implicit_data, VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR,
              "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12308", "dstImplicitData");

  // The op count: min(count in memory, maxAccelerationStructureCount); address 0: the max.
  uint64_t count = input.maxAccelerationStructureCount;
  if (command.srcInfosCount != 0) {
    try {
      uint32_t in_memory = memory.read<uint32_t>(count_address, {"srcInfosCount", -1});
      top.access(count_address, 4, kAccessIndirect, false, "srcInfosCount");
      if (in_memory > input.maxAccelerationStructureCount)
        top.finding("VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10453",
                    "srcInfosCount at " + hex(count_address) + " holds " + std::to_string(in_memory) +
                        ", more than input.maxAccelerationStructureCount = " +
                        std::to_string(input.maxAccelerationStructureCount) + "; the engine caps it",
                    count_address);
      count = std::min<uint64_t>(count, in_memory);
    } catch (const MemoryFault& fault) {
      top.fault(fault);
      count = 0;
    }
  }
  const uint64_t stride = cmd.src_infos.stride == 0 ? cmd.info_size : cmd.src_infos.stride;
  if (count > 0 && stride < cmd.info_size) {
    top.finding(src_infos_vuid(input.opType), "srcInfosArray.stride = " + std::to_string(stride) +
                                                   " is smaller than one src info (" + std::to_string(cmd.info_size) +
                                                   " bytes); no op runs");
    count = 0;
  }
  // Hostile counts: only as many ops as srcInfosArray really holds.
  if (count > 0) {
    uint64_t capacity = UINT64_MAX;
    std::string why;
    if (cmd.src_infos.size != 0) {
      capacity = elements_in(cmd.src_infos.size, stride, cmd.info_size);
      why = "srcInfosArray.size = " + std::to_string(cmd.src_infos.size);
    }
    const MemoryRegion* region = memory.find_region(cmd.src_infos.deviceAddress);
    uint64_t in_memory = region ? elements_in(region->base + region->size - cmd.src_infos.deviceAddress, stride,
                                              cmd.info_size)
                                : 0;
    if (in_memory < capacity) {
      capacity = in_memory;
      why = region ? "the memory at srcInfosArray (" + hex(cmd.src_infos.deviceAddress) + ", region '" +
                         region->label + "')"
                   : "no memory at srcInfosArray.deviceAddress " + hex(cmd.src_infos.deviceAddress);
    }
    if (count > capacity) {
      top.finding("VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10454",
                  "the op count is " + std::to_string(count) + " but " + why + " holds only " +
                      std::to_string(capacity) + " src infos; the engine runs those",
                  cmd.src_infos.deviceAddress);
      count = capacity;
    }
  }
  cmd.count = uint32_t(count);  // <= maxAccelerationStructureCount
  record.op_count = cmd.count;
  record.ops.resize(cmd.count);

  // 12305/12307 name a "device address range": every byte of the elements the ops use, up
  // to the last one's end (with no op, the first byte), must lie in a buffer with the usage.
  auto check_range_usage = [&](uint64_t address, uint64_t stride, uint64_t element, VkBufferUsageFlags bit,
                               const char* vuid, const char* what) {
    if (address == 0) return;
    uint64_t bytes = 1;
    if (cmd.count > 0) {
      const uint64_t step = stride == 0 ? element : stride;
      if (step != 0 && uint64_t(cmd.count - 1) > (UINT64_MAX - element) / step) return;  // wraps: faults say so
      bytes = uint64_t(cmd.count - 1) * step + element;
    }
    const uint64_t end = address + bytes < address ? UINT64_MAX : address + bytes;
    const std::optional<uint64_t> bad = options.first_without_usage
                                            ? options.first_without_usage(address, end, bit)
                                            : first_region_without_usage(memory, address, end, bit);
    if (!bad) return;
    const MemoryRegion* region = memory.find_region(*bad);
    top.finding(vuid, std::string(what) + " spans [" + hex(address) + ", " + hex(end) + "); its byte " + hex(*bad) +
                          (region ? " (buffer '" + region->label + "')" : std::string()) +
                          " lies in no buffer created with the usage it requires",
                *bad);
  };
  check_range_usage(cmd.src_infos.deviceAddress, stride, cmd.info_size,
                    VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR,
                    "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12305", "srcInfosArray");
  check_range_usage(cmd.dst_addresses.deviceAddress, cmd.dst_addresses.stride, 8,
                    VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR,
                    "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12307", "dstAddressesArray");

  // Scratch: the engine's (offset, size) table; 12300 against the queried size.
  BuildSizes queried = [&] {
    VkClusterAccelerationStructureInputInfoNV q = input;
    if (options.queried_max_count != 0) q.maxAccelerationStructureCount = options.queried_max_count;
    return cluster_build_sizes(q, props);
  }();
  bool scratch_usable = true;
  if (queried.build_scratch_size > 0) {
    const MemoryRegion* region = memory.find_region(cmd.scratch);
    uint64_t available = region ? region->base + region->size - cmd.scratch : 0;
    if (available < queried.build_scratch_size) {
      top.finding(kRuleScratchTooSmall, "scratchData " + hex(cmd.scratch) + " has " + std::to_string(available) +
                                            " bytes of memory, less than the " +
                                            std::to_string(queried.build_scratch_size) + " bytes the build sizes require",
                  cmd.scratch);
      scratch_usable = available >= scratch_bytes_for_ops(cmd.count);
    }
    if (props.clusterScratchByteAlignment > 1 && cmd.scratch % props.clusterScratchByteAlignment != 0)
      top.finding(kRuleScratchMisaligned, "scratchData " + hex(cmd.scratch) + " is not a multiple of clusterScratchByteAlignment = " +
                                              std::to_string(props.clusterScratchByteAlignment),
                  cmd.scratch);
  }
  const uint64_t align = destination_alignment(
      input.opType,
      input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV ? input.opInput.pMoveObjects->type
                                                                              : VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_MAX_ENUM_NV,
      props);
  if (implicit && cmd.count > 0 && cmd.implicit_data % align != 0)
    top.finding(kRuleDestinationMisaligned, "dstImplicitData " + hex(cmd.implicit_data) + " is not a multiple of the " +
                                                std::to_string(align) + "-byte object alignment",
                cmd.implicit_data);
  if (sizes_only && cmd.count > 0 && cmd.dst_sizes.deviceAddress == 0)
    top.finding(kRuleMissingSizesArray, "opMode is VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV but dstSizesArray is 0");

  finish();  // command-level findings come before the ops'

  // Ops, chunk by chunk.
  std::vector<MemoryAccess> op_accesses;
  std::vector<Written> written;      // destination objects
  std::vector<Written> move_sources;
  uint64_t cursor = 0;  // implicit packing offset
  uint64_t moved_bytes = 0, total_triangles = 0, total_vertices = 0, total_clusters = 0;
  const bool is_move = input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV;
  tbb::enumerable_thread_specific<ClusterBuilder> builders([&] { return ClusterBuilder(props); });
  for (uint64_t base = 0; base < cmd.count; base += kOpsPerChunk) {
    const uint32_t n = uint32_t(std::min<uint64_t>(kOpsPerChunk, cmd.count - base));
    std::vector<OpOutput> outs(n);
    tbb::parallel_for(uint32_t(0), n, [&](uint32_t k) {
      detail::run_op(cmd, memory, uint32_t(base + k), builders.local(), outs[k]);
    });
    // Write phase, op index order.
    std::vector<std::pair<uint64_t, const OpOutput*>> built;  // for the directory
    for (uint32_t k = 0; k < n; ++k) {
      OpOutput& out = outs[k];
      const uint32_t i = uint32_t(base + k);
      Recorder& rec = out.rec;
      OpResult& result = record.ops[i];
      const uint64_t size = out.ok ? out.bytes.size() : 0;
      total_triangles += out.triangles;
      total_vertices += out.vertices;
      total_clusters += out.clusters;
      if (out.ok) {
        result.dst_size = size;
        result.executed = true;
        result.dst_type = out.is_object ? VkClusterAccelerationStructureTypeNV(
                                              out.type == ObjectType::ClustersBottomLevel ? 0 : out.type == ObjectType::TriangleCluster ? 1 : 2)
                                        : VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_MAX_ENUM_NV;
        if (is_move) {
          moved_bytes = sat_add(moved_bytes, size);
          move_sources.push_back({out.move_src, out.move_src + out.move_src_size, i});
        }
      }
      uint64_t dst = 0;
      if (out.ok && implicit) {
        uint64_t offset = align_up_sat(cursor, align);
        dst = cmd.implicit_data + offset;
        cursor = sat_add(offset, size);
        if (dst < cmd.implicit_data) dst = 0;  // wrapped: the write below faults
      } else if (out.ok && explicit_mode) {
        dst = out.explicit_dst;
        if (dst % align != 0)
          rec.finding(kRuleDestinationMisaligned, "dstAddressesArray[" + std::to_string(i) + "] = " + hex(dst) +
                                                      " is not a multiple of the " + std::to_string(align) +
                                                      "-byte object alignment",
                      dst);
      }
      std::string where = implicit ? "dstImplicitData[op " + std::to_string(i) + "]"
                                   : "*dstAddressesArray[" + std::to_string(i) + "]";
      if (out.ok && !sizes_only) {
        try {
          auto span = memory.write_bytes(dst, size, {where.c_str(), i});
          std::copy(out.bytes.begin(), out.bytes.end(), span.begin());
          rec.access(dst, size, kAccessObjectWrite, true, where);
          result.dst_address = dst;
          written.push_back({dst, dst + size, i});
          built.push_back({dst, &out});
        } catch (const MemoryFault& fault) {
          rec.fault(fault);
          result.executed = false;
        }
      }
      try {
        if (implicit && cmd.dst_addresses.deviceAddress != 0) {
          std::string f = "dstAddressesArray[" + std::to_string(i) + "]";
          uint64_t a = MemoryImage::strided_address(cmd.dst_addresses, i, 8, {f.c_str(), i});
          memory.write<uint64_t>(a, result.dst_address, {f.c_str(), i});
          rec.access(a, 8, kAccessObjectWrite, true, f);
        }
        if ((implicit || sizes_only) && cmd.dst_sizes.deviceAddress != 0) {
          std::string f = "dstSizesArray[" + std::to_string(i) + "]";
          uint64_t a = MemoryImage::strided_address(cmd.dst_sizes, i, 4, {f.c_str(), i});
          uint32_t s = result.executed || (sizes_only && out.ok) ? uint32_t(size) : 0;
          memory.write<uint32_t>(a, s, {f.c_str(), i});
          rec.access(a, 4, kAccessObjectWrite, true, f);
        }
      } catch (const MemoryFault& fault) {
        rec.fault(fault);
      }
      if (scratch_usable && cmd.scratch != 0) {
        uint64_t entry[2] = {dst == 0 ? 0 : dst - (implicit ? cmd.implicit_data : 0), size};
        try {
          std::memcpy(memory.write_bytes(cmd.scratch + uint64_t(i) * 16, 16, {"scratchData", i}).data(), entry, 16);
        } catch (const MemoryFault& fault) {
          rec.fault(fault);
          scratch_usable = false;
        }
      }
      for (auto& f : rec.findings) sink.add(std::move(f));
      rec.findings.clear();
      for (auto& a : rec.accesses) op_accesses.push_back(std::move(a));
    }
    // Directory: retire move sources first, so a swap (A->B, B->A) leaves both live.
    if (is_move && !input.opInput.pMoveObjects->noMoveOverlap)
      for (auto& [dst, out] : built) directory.record_moved_away(out->move_src, dst);
    for (auto& [dst, out] : built)
      if (out->is_object) directory.record_built(dst, out->type, out->bytes);
  }
  record.implicit_bytes_used = implicit ? cursor : 0;
  if (cmd.scratch != 0 && cmd.count > 0) {
    record.scratch_bytes_used = scratch_bytes_for_ops(cmd.count);
    top.access(cmd.scratch, record.scratch_bytes_used, kAccessScratch, true, "scratchData");
  }

  // What only the whole command shows.
  auto overlap_check = [&](std::vector<Written> v, const char* rule, const char* what) {
    std::sort(v.begin(), v.end(), [](const Written& a, const Written& b) { return a.begin < b.begin || (a.begin == b.begin && a.op < b.op); });
    uint64_t reach = 0;
    int64_t reach_op = -1;
    for (const Written& w : v) {
      if (reach_op >= 0 && w.begin < reach)
        top.finding(rule, std::string(what) + ": op " + std::to_string(w.op) + "'s object [" + hex(w.begin) + ", " +
                              hex(w.end) + ") overlaps op " + std::to_string(reach_op) + "'s, which ends at " + hex(reach) +
                              " (the higher op index's bytes are kept)",
                    w.begin);
      if (w.end > reach) {
        reach = w.end;
        reach_op = w.op;
      }
    }
  };
  if (explicit_mode) overlap_check(written, "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-dstAddressesArray-12302",
                                   "destinations in dstAddressesArray overlap");
  if (cmd.scratch != 0 && record.scratch_bytes_used > 0) {
    uint64_t s0 = cmd.scratch, s1 = cmd.scratch + record.scratch_bytes_used;
    if (implicit && cursor > 0 && cmd.implicit_data < s1 && s0 < cmd.implicit_data + cursor)
      top.finding("VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-dstImplicitData-12303",
                  "dstImplicitData [" + hex(cmd.implicit_data) + ", " + hex(cmd.implicit_data + cursor) +
                      ") overlaps scratchData [" + hex(s0) + ", " + hex(s1) + ")",
                  cmd.implicit_data);
    if (explicit_mode)
      for (const Written& w : written)
        if (w.begin < s1 && s0 < w.end)
          top.finding("VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-dstAddressesArray-12302",
                      "op " + std::to_string(w.op) + "'s destination [" + hex(w.begin) + ", " + hex(w.end) +
                          ") overlaps scratchData [" + hex(s0) + ", " + hex(s1) + ")",
                      w.begin);
  }
  if (is_move) {
    const auto& mv = *input.opInput.pMoveObjects;
    if (moved_bytes > mv.maxMovedBytes)
      top.finding(kRuleMovedBytesAboveInput, "the command moves " + std::to_string(moved_bytes) +
                                                 " bytes, more than maxMovedBytes = " + std::to_string(mv.maxMovedBytes));
    if (mv.noMoveOverlap) {
      std::vector<Written> dsts = written;
      std::sort(dsts.begin(), dsts.end(), [](const Written& a, const Written& b) { return a.op < b.op; });
      for (const Written& src : move_sources) {
        auto it = std::lower_bound(dsts.begin(), dsts.end(), src.op, [](const Written& w, int64_t op) { return w.op < op; });
        if (it != dsts.end() && it->op == src.op && it->begin < src.end && src.begin < it->end)
          top.finding(kRuleMoveOverlap, "op " + std::to_string(src.op) + " moves [" + hex(src.begin) + ", " +
                                            hex(src.end) + ") onto an overlapping destination at " + hex(it->begin) +
                                            " although noMoveOverlap is VK_TRUE",
                      src.begin);
      }
    }
  } else if (input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV) {
    const auto& bl = *input.opInput.pClustersBottomLevel;
    if (total_clusters > bl.maxTotalClusterCount)
      top.finding(kRuleTotalAboveInput, "the command references " + std::to_string(total_clusters) +
                                            " clusters, more than maxTotalClusterCount = " +
                                            std::to_string(bl.maxTotalClusterCount));
  } else if (input.opType != VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV) {
    const auto& tc = *input.opInput.pTriangleClusters;
    if (total_triangles > tc.maxTotalTriangleCount)
      top.finding(kRuleTotalAboveInput, "the command builds " + std::to_string(total_triangles) +
                                            " triangles, more than maxTotalTriangleCount = " +
                                            std::to_string(tc.maxTotalTriangleCount));
    if (total_vertices > tc.maxTotalVertexCount)
      top.finding(kRuleTotalAboveInput, "the command builds " + std::to_string(total_vertices) +
                                            " vertices, more than maxTotalVertexCount = " +
                                            std::to_string(tc.maxTotalVertexCount));
  }
  // No order exists between the ops of one command: a range one op reads and another
  // op (or the same op, through another field) writes is undefined on a GPU. (Moves
  // without noMoveOverlap may overlap their own source: the spec allows it.)
  {
    std::vector<const MemoryAccess*> writes;
    for (const auto& a : op_accesses)
      if (a.is_write) writes.push_back(&a);
    std::sort(writes.begin(), writes.end(), [](const MemoryAccess* a, const MemoryAccess* b) {
      return a->begin < b->begin || (a->begin == b->begin && a->op_index < b->op_index);
    });
    // Per read, the earlier-starting write that reaches furthest: one finding per read,
    // O(log n) each, however the writes nest.
    std::vector<size_t> reach(writes.size());
    for (size_t k = 0; k < writes.size(); ++k)
      reach[k] = k && writes[reach[k - 1]]->end >= writes[k]->end ? reach[k - 1] : k;
    uint64_t hazards = 0;
    auto check_read = [&](const MemoryAccess& read) {
      if (read.is_write) return;
      auto it = std::lower_bound(writes.begin(), writes.end(), read.end,
                                 [](const MemoryAccess* w, uint64_t v) { return w->begin < v; });
      if (it == writes.begin()) return;
      const MemoryAccess& w = *writes[reach[size_t(it - writes.begin()) - 1]];
      if (w.end <= read.begin) return;
      if (is_move && w.op_index == read.op_index) return;  // a move may overlap its own source
      if (++hazards > options.max_findings_per_rule) {  // counted by the sink, not spelled out
        top.finding(kRuleIntraCommandHazard, "");
        return;
      }
      top.finding(kRuleIntraCommandHazard,
                  "op " + std::to_string(read.op_index) + " reads " + read.field + " [" + hex(read.begin) + ", " +
                      hex(read.end) + ") which op " + std::to_string(w.op_index) + " writes as " + w.field +
                      " in the same command",
                  std::max(read.begin, w.begin));
    };
    for (const auto& a : top.accesses) check_read(a);  // srcInfosCount, indirection cells
    for (const auto& a : op_accesses) check_read(a);
  }
  finish();
  sink.close();
  record.accesses = std::move(top.accesses);
  record.accesses.insert(record.accesses.end(), std::make_move_iterator(op_accesses.begin()),
                         std::make_move_iterator(op_accesses.end()));
  return record;
}

}  // namespace clastrace::engine
