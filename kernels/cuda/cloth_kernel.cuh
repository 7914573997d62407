/* cloth_kernel.cuh - what the CUDA backend's kernels and its host code share: the device memory
 * accessors, the sizes of a block, the scene struct and the buffers a launch works on, the modes
 * the kernels run in. Part of the one translation unit backend_cuda.cu. */
#ifndef CLOTHSIM_CUDA_CLOTH_KERNEL_CUH
#define CLOTHSIM_CUDA_CLOTH_KERNEL_CUH

#include <cuda_runtime.h>

#include "clothsim/backend.h"
#include "clothsim/physics.h"

/* Device memory access: the CPU imitation of CUDA (tests/emu) counts bytes through these. */
#ifndef CS_DEVMEM_HOOKS
template <class T> __device__ __forceinline__ T dload(const T *p) { return *p; }
template <class T> __device__ __forceinline__ void dstore(T *p, T v) { *p = v; }
/* What other blocks of the same launch wrote: from L2, past this SM's L1. */
template <class T> __device__ __forceinline__ T dload_cg(const T *p) { return __ldcg(p); }
#endif
#ifndef CS_DYNAMIC_SHARED
#define CS_DYNAMIC_SHARED(T, name)                                                                     \
    extern __shared__ __align__(16) unsigned char cs_dynamic_smem[];                                  \
    T *name = reinterpret_cast<T *>(cs_dynamic_smem)
#endif

#define TILE_W CS_CHUNK            /* threads of a cloth block: the columns of one chunk */
#define RING_OFF 3                 /* ring rows hold columns c0 - 3 .. c0 + 258 */
#define RING_W (TILE_W + 6)
#define FORCE_OFF 2                /* force rows hold columns c0 - 2 .. c0 + 257 */
#define FORCE_W (TILE_W + 4)
#define WARPS (TILE_W / 32)
#define MAX_TILE_ROWS 8
#define ROCKS_FUSED 64             /* up to this many rocks, one block sums and moves them all */
#define ROCK_WARPS 8               /* rocks per block of the split rock kernel */
#define GRAPH_MAX 256              /* most substeps in one graph */
#define GRAPHS 8                   /* graphs kept */
#define FULL 0xffffffffu

static_assert(CS_CHUNK_GROUP == 64, "a chunk group's chunks are the bits of one 64-bit word");
static_assert(TILE_W % 32 == 0 && TILE_W <= 1024, "a chunk is whole warps");

/* What the kernels read for one scene (one struct: a per-scene table can replace it). */

struct cuda_scene {
    cs_phys p;
    int32_t nr;          /* rocks */
    int32_t grab;        /* grabbed vertex or -1 */
    cs_vec3 grab_target;
    int32_t tile_rows;   /* rows of a cloth block */
    int32_t ngroups;     /* chunk groups: ceil(nchunks / CS_CHUNK_GROUP) */
};

/* The arrays one launch works on (by value: a graph node holds them). */
struct cuda_bufs {
    const float *in;             /* x, y, z, vx, vy, vz: the state read (6 n) */
    float *out;                  /* the state written (6 n) */
    const unsigned char *mask;   /* 1 free, 0 pinned or grabbed (n) */
    float *acc;                  /* ax, ay, az (3 n) */
    const float *L0;             /* rest lengths read (6 n, type-major) */
    float *L0n;                  /* the other buffer: written where a vertex's springs changed */
    unsigned char *chg;          /* 1 where the vertex's rest lengths changed in the last update */
    cs_rock_state *rocks;
    float *partials;             /* [rock][chunk][6]: a chunk's force and torque on a rock */
    unsigned long long *hits;    /* [rock][group]: bit c % 64 set when chunk c wrote its partial */
    float *gsum;                 /* [rock][group][6]: a chunk group's force and torque on a rock */
    int *group_done;             /* [group]: chunks of the group done this launch */
    int *flags;
};

enum { FLAG_TORN = 0, FLAG_NONFINITE = 1, FLAG_COUNT = 2 };

/* What the cloth kernel does after the forces. */
enum {
    MODE_ACCEL,       /* store a only (refresh after a command) */
    MODE_VERLET,      /* finish this substep's kick, start the next one's kick and drift */
    MODE_VERLET_LAST, /* finish the kick; store a */
    MODE_EULER,       /* v += dt a; x += dt v */
    MODE_EULER_LAST   /* the same, and store a */
};
/* What the rock kernels do after the forces. */
enum { ROCKS_ACCEL, ROCKS_VERLET, ROCKS_VERLET_LAST, ROCKS_EULER, ROCKS_FIRST };

__device__ static inline int finite3(cs_vec3 v) { return isfinite(v.x) && isfinite(v.y) && isfinite(v.z); }

#endif /* CLOTHSIM_CUDA_CLOTH_KERNEL_CUH */
