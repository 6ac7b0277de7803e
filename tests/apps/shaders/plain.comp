// SPDX-License-Identifier: Apache-2.0
// ray_consumers_app: a dispatch that traces nothing (its record must carry no ray query).
#version 460
layout(local_size_x = 1) in;

layout(set = 0, binding = 1, std430) buffer Results {
    uint values[];
} results;

void main() { results.values[1] = 7u; }
