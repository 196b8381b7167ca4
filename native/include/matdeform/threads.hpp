// Thread count of the core's parallel loops (OpenMP). Hosts with their own worker pools (e.g.
// Blender) may prefer 1 thread to avoid cores being oversubscribed.
#pragma once

namespace matdeform {

void set_num_threads(int n);  // n >= 1
int num_threads();            // 1 when built without OpenMP

}  // namespace matdeform
