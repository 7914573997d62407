/* tests/emu/cuda_runtime.h - a CPU imitation of the part of the CUDA runtime that
 * kernels/cuda/backend_cuda.cu uses. TESTS ONLY: it is never built into libclothsim or clothd.
 *
 * tests/emu/CMakeLists.txt compiles backend_cuda.cu itself with the host C++ compiler against this
 * header (each `kernel<<<grid, block, smem, stream>>>(args)` rewritten by emu_launch.cmake into
 * `emu::launch("kernel", kernel, grid, block, smem, stream)(args)`), so the real kernel source
 * runs in ctest on every CI machine and can be compared bit for bit with the CPU backend.
 *
 * What it imitates: the threads of a block run as cooperative fibers, so __syncthreads, its
 * _or/_count forms, warp shuffles, ballots and dynamic shared memory behave as on a GPU (a barrier
 * that not every live thread of the block reaches, or a warp operation whose lanes did not all
 * arrive, stops the program with a diagnosis); blocks spread over OpenMP threads; streams run
 * lazily, in order, when something waits on them (a host read of pinned memory before the stream
 * ran shows stale bytes, as it would on a GPU); events, stream capture, graphs (instantiate,
 * update, launch); device and pinned allocations filled with 0xff bytes (a NaN as float) so a read
 * of memory nothing wrote shows up. It counts launches, graph rebuilds and copied bytes, and can
 * count the distinct bytes each kernel launch reads and writes (tests/emu/emu.h).
 *
 * What it is not: GPU machine code, timing, memory ordering between blocks, or the device's
 * limits beyond the few it checks (1,024 threads a block, 48 KiB of dynamic shared memory).
 * Races between blocks of one launch do not show here: compute-sanitizer on a GPU
 * (tests/gpu/run.sh) looks for those. */
#ifndef CLOTHD_EMU_CUDA_RUNTIME_H
#define CLOTHD_EMU_CUDA_RUNTIME_H

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <functional>
#include <tuple>
#include <type_traits>
#include <utility>

#define CS_CUDA_EMU 1

/* ---- qualifiers ---- */
#define __global__
#define __device__
#define __host__
#define __forceinline__ inline __attribute__((always_inline))
#define __restrict__ __restrict
#define __launch_bounds__(...)
/* A static __shared__ array is one per OS thread here (blocks run one at a time on each), zeroed
 * once and never refilled: dynamic shared memory (CS_DYNAMIC_SHARED below) is filled with 0xff
 * bytes for every block, so prefer it. */
#define __shared__ static thread_local

/* ---- vector types ---- */
struct uint3 {
    unsigned x, y, z;
};
struct dim3 {
    unsigned x, y, z;
    dim3(unsigned x_ = 1, unsigned y_ = 1, unsigned z_ = 1) : x(x_), y(y_), z(z_) {}
};
struct float2 {
    float x, y;
};
struct float4 {
    float x, y, z, w;
};
struct int2 {
    int x, y;
};
static inline float2 make_float2(float x, float y) { return float2{x, y}; }
static inline float4 make_float4(float x, float y, float z, float w) { return float4{x, y, z, w}; }

/* ---- device-side built-ins ---- */
namespace emu {
struct thread_view {
    uint3 tid, bid;
    dim3 bdim, gdim;
};
/* The imitated thread running on this OS thread. A function, not an extern thread_local: C++'s
 * lazy initialization of another file's thread_locals would run on a fiber's first access. */
thread_view *current();

void syncthreads();
int syncthreads_reduce(int kind, int pred); /* 1 or, 2 and, 3 count */
uint64_t warp_op(int op, unsigned mask, uint64_t value, int arg, int width);
void *dynamic_shared();
void touch(const void *p, size_t bytes, int write);
extern int counting; /* emu_count_bytes */

enum { WARP_SHFL, WARP_SHFL_DOWN, WARP_SHFL_UP, WARP_SHFL_XOR, WARP_BALLOT, WARP_SYNC };

template <class T> static inline T warp_shuffle(int op, unsigned mask, T v, int arg, int width)
{
    static_assert(sizeof(T) <= 8 && std::is_trivially_copyable<T>::value, "shuffled values are 4 or 8 bytes");
    uint64_t bits = 0;
    std::memcpy(&bits, &v, sizeof v);
    bits = warp_op(op, mask, bits, arg, width);
    T r;
    std::memcpy(&r, &bits, sizeof r);
    return r;
}
} // namespace emu

#define threadIdx (emu::current()->tid)
#define blockIdx (emu::current()->bid)
#define blockDim (emu::current()->bdim)
#define gridDim (emu::current()->gdim)
#define warpSize 32

static inline void __syncthreads() { emu::syncthreads(); }
static inline int __syncthreads_or(int p) { return emu::syncthreads_reduce(1, p); }
static inline int __syncthreads_and(int p) { return emu::syncthreads_reduce(2, p); }
static inline int __syncthreads_count(int p) { return emu::syncthreads_reduce(3, p); }
static inline void __syncwarp(unsigned mask = 0xffffffffu) { emu::warp_op(emu::WARP_SYNC, mask, 0, 0, 32); }
static inline void __threadfence() { __atomic_thread_fence(__ATOMIC_SEQ_CST); }
static inline void __threadfence_block() { __atomic_thread_fence(__ATOMIC_SEQ_CST); }
template <class T> static inline T __shfl_sync(unsigned m, T v, int src, int w = 32)
{
    return emu::warp_shuffle(emu::WARP_SHFL, m, v, src, w);
}
template <class T> static inline T __shfl_down_sync(unsigned m, T v, unsigned d, int w = 32)
{
    return emu::warp_shuffle(emu::WARP_SHFL_DOWN, m, v, (int)d, w);
}
template <class T> static inline T __shfl_up_sync(unsigned m, T v, unsigned d, int w = 32)
{
    return emu::warp_shuffle(emu::WARP_SHFL_UP, m, v, (int)d, w);
}
template <class T> static inline T __shfl_xor_sync(unsigned m, T v, int lm, int w = 32)
{
    return emu::warp_shuffle(emu::WARP_SHFL_XOR, m, v, lm, w);
}
static inline unsigned __ballot_sync(unsigned m, int p) { return (unsigned)emu::warp_op(emu::WARP_BALLOT, m, p != 0, 0, 32); }
static inline int __any_sync(unsigned m, int p) { return __ballot_sync(m, p) != 0; }
static inline int __all_sync(unsigned m, int p) { return (__ballot_sync(m, p) & m) == m; }
static inline int __popc(unsigned x) { return __builtin_popcount(x); }
static inline int __popcll(unsigned long long x) { return __builtin_popcountll(x); }
static inline int __ffs(int x) { return __builtin_ffs(x); }
static inline int __ffsll(long long x) { return __builtin_ffsll(x); }
static inline int __clz(int x) { return x ? __builtin_clz((unsigned)x) : 32; }

static inline unsigned __float_as_uint(float f)
{
    unsigned u;
    std::memcpy(&u, &f, sizeof u);
    return u;
}
static inline float __uint_as_float(unsigned u)
{
    float f;
    std::memcpy(&f, &u, sizeof f);
    return f;
}

/* Atomics: blocks of one launch run on several OS threads at once. Not counted as traffic. */
template <class T> static inline T atomicAdd(T *p, T v) { return __atomic_fetch_add(p, v, __ATOMIC_SEQ_CST); }
template <class T> static inline T atomicOr(T *p, T v) { return __atomic_fetch_or(p, v, __ATOMIC_SEQ_CST); }
template <class T> static inline T atomicAnd(T *p, T v) { return __atomic_fetch_and(p, v, __ATOMIC_SEQ_CST); }

/* Dynamic shared memory (the launch's third parameter), 0xff-filled at the start of each block. */
#define CS_DYNAMIC_SHARED(T, name) T *name = static_cast<T *>(emu::dynamic_shared())

/* Device memory loads and stores of the kernels: counted when emu_count_bytes(1) is on. */
#define CS_DEVMEM_HOOKS 1
template <class T> static inline T dload(const T *p)
{
    if (emu::counting) emu::touch(p, sizeof(T), 0);
    return *p;
}
template <class T> static inline void dstore(T *p, T v)
{
    if (emu::counting) emu::touch(p, sizeof(T), 1);
    *p = v;
}
template <class T> static inline T dload_cg(const T *p) { return dload(p); }

/* ---- host API ---- */
typedef enum cudaError {
    cudaSuccess = 0,
    cudaErrorInvalidValue = 1,
    cudaErrorMemoryAllocation = 2,
    cudaErrorInitializationError = 3,
    cudaErrorInvalidConfiguration = 9,
    cudaErrorNoDevice = 100,
    cudaErrorInvalidDevice = 101,
    cudaErrorECCUncorrectable = 214,
    cudaErrorInvalidResourceHandle = 400,
    cudaErrorIllegalState = 401,
    cudaErrorNotReady = 600,
    cudaErrorIllegalAddress = 700,
    cudaErrorLaunchOutOfResources = 701,
    cudaErrorLaunchTimeout = 702,
    cudaErrorAssert = 710,
    cudaErrorHardwareStackError = 714,
    cudaErrorIllegalInstruction = 715,
    cudaErrorMisalignedAddress = 716,
    cudaErrorInvalidAddressSpace = 717,
    cudaErrorInvalidPc = 718,
    cudaErrorLaunchFailure = 719,
    cudaErrorStreamCaptureUnsupported = 900,
    cudaErrorStreamCaptureInvalidated = 901,
    cudaErrorStreamCaptureUnjoined = 904,
    cudaErrorStreamCaptureIsolation = 905,
    cudaErrorCapturedEvent = 907,
    cudaErrorStreamCaptureWrongThread = 908,
    cudaErrorGraphExecUpdateFailure = 910,
    cudaErrorUnknown = 999
} cudaError_t;

enum cudaMemcpyKind {
    cudaMemcpyHostToHost = 0,
    cudaMemcpyHostToDevice = 1,
    cudaMemcpyDeviceToHost = 2,
    cudaMemcpyDeviceToDevice = 3,
    cudaMemcpyDefault = 4
};
enum cudaStreamCaptureMode {
    cudaStreamCaptureModeGlobal = 0,
    cudaStreamCaptureModeThreadLocal = 1,
    cudaStreamCaptureModeRelaxed = 2
};
enum cudaDeviceAttr {
    cudaDevAttrMultiProcessorCount = 16,
    cudaDevAttrMemoryClockRate = 36,
    cudaDevAttrGlobalMemoryBusWidth = 37
};
enum cudaGraphExecUpdateResult {
    cudaGraphExecUpdateSuccess = 0,
    cudaGraphExecUpdateError = 1,
    cudaGraphExecUpdateErrorTopologyChanged = 2,
    cudaGraphExecUpdateErrorNodeTypeChanged = 3,
    cudaGraphExecUpdateErrorFunctionChanged = 4,
    cudaGraphExecUpdateErrorParametersChanged = 5
};
#define cudaStreamDefault 0x0u
#define cudaStreamNonBlocking 0x1u
#define cudaEventDefault 0x0u
#define cudaEventDisableTiming 0x2u
#define cudaHostAllocDefault 0x0u

typedef struct emu_stream *cudaStream_t;
typedef struct emu_event *cudaEvent_t;
typedef struct emu_graph *cudaGraph_t;
typedef struct emu_graph_exec *cudaGraphExec_t;
typedef struct emu_graph_node *cudaGraphNode_t;
struct cudaGraphExecUpdateResultInfo {
    cudaGraphExecUpdateResult result;
    cudaGraphNode_t errorNode, errorFromNode;
};
struct cudaDeviceProp {
    char name[256];
    int major, minor, multiProcessorCount, memoryBusWidth;
    size_t totalGlobalMem;
};

const char *cudaGetErrorString(cudaError_t e);
const char *cudaGetErrorName(cudaError_t e);
cudaError_t cudaGetLastError(void);
cudaError_t cudaPeekAtLastError(void);
cudaError_t cudaGetDeviceCount(int *count);
cudaError_t cudaGetDevice(int *dev);
cudaError_t cudaSetDevice(int dev);
cudaError_t cudaGetDeviceProperties(cudaDeviceProp *prop, int dev);
cudaError_t cudaDeviceGetAttribute(int *value, cudaDeviceAttr attr, int dev);
cudaError_t cudaDeviceSynchronize(void);

cudaError_t cudaMalloc(void **p, size_t bytes);
cudaError_t cudaFree(void *p);
cudaError_t cudaMallocHost(void **p, size_t bytes);
cudaError_t cudaHostAlloc(void **p, size_t bytes, unsigned flags);
cudaError_t cudaFreeHost(void *p);
cudaError_t cudaMemcpy(void *dst, const void *src, size_t bytes, cudaMemcpyKind kind);
cudaError_t cudaMemcpyAsync(void *dst, const void *src, size_t bytes, cudaMemcpyKind kind, cudaStream_t s = 0);
cudaError_t cudaMemset(void *dst, int value, size_t bytes);
cudaError_t cudaMemsetAsync(void *dst, int value, size_t bytes, cudaStream_t s = 0);

cudaError_t cudaStreamCreate(cudaStream_t *s);
cudaError_t cudaStreamCreateWithFlags(cudaStream_t *s, unsigned flags);
cudaError_t cudaStreamDestroy(cudaStream_t s);
cudaError_t cudaStreamSynchronize(cudaStream_t s);
cudaError_t cudaStreamQuery(cudaStream_t s);
cudaError_t cudaStreamWaitEvent(cudaStream_t s, cudaEvent_t e, unsigned flags = 0);
cudaError_t cudaEventCreate(cudaEvent_t *e);
cudaError_t cudaEventCreateWithFlags(cudaEvent_t *e, unsigned flags);
cudaError_t cudaEventDestroy(cudaEvent_t e);
cudaError_t cudaEventRecord(cudaEvent_t e, cudaStream_t s = 0);
cudaError_t cudaEventSynchronize(cudaEvent_t e);
cudaError_t cudaEventQuery(cudaEvent_t e);
/* The imitation keeps no time: every interval is 1 ms. */
cudaError_t cudaEventElapsedTime(float *ms, cudaEvent_t a, cudaEvent_t b);

cudaError_t cudaStreamBeginCapture(cudaStream_t s, cudaStreamCaptureMode mode);
cudaError_t cudaStreamEndCapture(cudaStream_t s, cudaGraph_t *g);
cudaError_t cudaGraphDestroy(cudaGraph_t g);
cudaError_t cudaGraphInstantiate(cudaGraphExec_t *exec, cudaGraph_t g, unsigned long long flags = 0);
cudaError_t cudaGraphExecUpdate(cudaGraphExec_t exec, cudaGraph_t g, cudaGraphExecUpdateResultInfo *info);
cudaError_t cudaGraphExecDestroy(cudaGraphExec_t exec);
cudaError_t cudaGraphLaunch(cudaGraphExec_t exec, cudaStream_t s);

/* ---- launches ---- */
namespace emu {
struct kernel_task {
    const char *name;
    const void *fn; /* identity of the kernel, for graph updates */
    dim3 grid, block;
    size_t smem;
    std::function<void()> body; /* runs the kernel for the current imitated thread */
};
void enqueue_kernel(cudaStream_t s, kernel_task &&t);

template <class... P> struct launcher {
    const char *name;
    void (*fn)(P...);
    dim3 grid, block;
    size_t smem;
    cudaStream_t stream;
    /* Parameters by value, converted as a call would convert them. */
    void operator()(P... a) const
    {
        void (*f)(P...) = fn;
        std::tuple<typename std::decay<P>::type...> args(a...);
        enqueue_kernel(stream, kernel_task{name, reinterpret_cast<const void *>(f), grid, block, smem,
                                           [f, args]() { std::apply(f, args); }});
    }
};
template <class... P>
static inline launcher<P...> launch(const char *name, void (*fn)(P...), dim3 grid, dim3 block, size_t smem = 0,
                                    cudaStream_t stream = 0)
{
    return launcher<P...>{name, fn, grid, block, smem, stream};
}
} // namespace emu

#endif
