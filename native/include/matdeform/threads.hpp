// Thread count of the core's parallel loops (its task pool and its OpenMP loops). Hosts with
// their own worker pools (e.g. Blender) may prefer 1 thread to avoid cores being oversubscribed.
#pragma once

namespace matdeform {

// Process-wide: every thread, also one started later, sees the value set last. n >= 1.
void set_num_threads(int n);
// The value set last; before any set_num_threads, OpenMP's default (OMP_NUM_THREADS or the
// core count), or 1 when built without OpenMP.
int num_threads();

}  // namespace matdeform
