/* tests/emu/emu.cc - the CPU imitation of the CUDA runtime declared in cuda_runtime.h (tests only;
 * what it is and is not: see that header).
 *
 * Host side: allocations are malloc'd and filled with 0xff; a stream is a queue of operations run
 * in order on the calling thread when something waits on it (cudaStreamSynchronize, an event, a
 * synchronous copy, a copy to pageable memory), so work a host thread did not wait for has not
 * happened yet. A capturing stream appends its operations to a graph instead; an instantiated
 * graph replays them in capture order.
 *
 * Device side: a launch runs its blocks over OpenMP threads. Each OS thread keeps a pool of
 * fibers (ucontext stacks, switched with __builtin_setjmp/__builtin_longjmp, which do not make a
 * system call) and runs a block's threads on them: a fiber runs until it reaches a barrier or a
 * warp operation, then the next one runs; when every live thread of the block waits at the
 * barrier (or every lane named in a warp operation's mask waits at it) they are released with
 * the operation's result. Anything else - a barrier not all live threads reach, lanes that meet
 * at different warp operations - is a bug in the kernel: the program stops with a diagnosis. */
#include "cuda_runtime.h"
#include "emu.h"

#include <sys/mman.h>
#include <ucontext.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>
#ifdef _OPENMP
#include <omp.h>
#endif

#if defined(__SANITIZE_ADDRESS__)
#define EMU_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define EMU_ASAN 1
#endif
#endif
#ifdef EMU_ASAN
#include <sanitizer/common_interface_defs.h>
#define START_SWITCH(save, bottom, size) __sanitizer_start_switch_fiber((save), (bottom), (size))
#define FINISH_SWITCH(save, bottom, size) __sanitizer_finish_switch_fiber((save), (bottom), (size))
#else
#define START_SWITCH(save, bottom, size) ((void)(save), (void)(bottom), (void)(size))
#define FINISH_SWITCH(save, bottom, size) ((void)(save), (void)(bottom), (void)(size))
#endif

namespace emu {
static thread_local thread_view *cur;
thread_view *current() { return cur; }
int counting;
} // namespace emu

namespace {

[[noreturn]] void die(const char *why)
{
    std::fprintf(stderr, "cuda emulation: %s\n", why);
    std::abort();
}

/* ---- counters and faults ---- */

emu_counters counters;
int fail_alloc = -1;
cudaError_t dead = cudaSuccess;
thread_local cudaError_t last_error = cudaSuccess;

struct kstats {
    std::string name;
    uint64_t launches = 0, threads = 0, read = 0, written = 0, loads = 0, stores = 0, counted = 0;
};
std::vector<kstats> kernel_stats;
std::map<std::string, size_t> kernel_index;

cudaError_t fail(cudaError_t e)
{
    last_error = e;
    return e;
}

/* ---- allocations ---- */

struct alloc {
    size_t bytes;
    bool pinned;
    std::vector<uint64_t> rbits, wbits; /* one bit a byte, while counting */
    int touched;
};
std::map<uintptr_t, alloc> allocs;

/* The allocation holding [p, p + bytes), or NULL. */
alloc *find(const void *p, size_t bytes, uintptr_t *base = nullptr)
{
    const uintptr_t a = (uintptr_t)p;
    auto it = allocs.upper_bound(a);
    if (it == allocs.begin()) return nullptr;
    --it;
    if (a < it->first || a + bytes > it->first + it->second.bytes || a + bytes < a) return nullptr;
    if (base) *base = it->first;
    return &it->second;
}

cudaError_t allocate(void **p, size_t bytes, bool pinned)
{
    if (!p) return fail(cudaErrorInvalidValue);
    *p = nullptr;
    if (dead) return fail(dead);
    if (fail_alloc == 0) {
        fail_alloc = -1;
        return fail(cudaErrorMemoryAllocation);
    }
    if (fail_alloc > 0) fail_alloc--;
    void *m = std::malloc(bytes ? bytes : 1);
    if (!m) return fail(cudaErrorMemoryAllocation);
    std::memset(m, 0xff, bytes); /* a NaN in every float nothing has written */
    allocs[(uintptr_t)m] = alloc{bytes, pinned, {}, {}, 0};
    if (pinned) {
        counters.pinned_bytes += bytes;
    } else {
        counters.device_bytes += bytes;
        if (counters.device_bytes > counters.device_bytes_peak) counters.device_bytes_peak = counters.device_bytes;
    }
    *p = m;
    return cudaSuccess;
}

cudaError_t release(void *p, bool pinned)
{
    if (!p) return cudaSuccess;
    auto it = allocs.find((uintptr_t)p);
    if (it == allocs.end() || it->second.pinned != pinned) return fail(cudaErrorInvalidValue);
    (pinned ? counters.pinned_bytes : counters.device_bytes) -= it->second.bytes;
    allocs.erase(it);
    std::free(p);
    return cudaSuccess;
}

/* ---- operations, streams, events, graphs ---- */

enum node_kind { NODE_KERNEL, NODE_COPY, NODE_SET };
struct node {
    node_kind kind;
    emu::kernel_task k;
    void *dst;
    const void *src;
    size_t bytes;
    int value;
    cudaMemcpyKind ckind;
};
typedef std::shared_ptr<const std::vector<node>> node_list;

enum op_kind { OP_NODE, OP_WAIT, OP_GRAPH };
struct op {
    op_kind kind;
    node n;
    emu_stream *ws; /* OP_WAIT: run this stream up to wt first */
    uint64_t wt;
    node_list g;
};

} // namespace

struct emu_stream {
    std::deque<op> q;
    uint64_t enqueued = 0, done = 0;
    emu_graph *capture = nullptr;
    bool capture_bad = false;
};
struct emu_event {
    emu_stream *s = nullptr;
    uint64_t target = 0;
};
struct emu_graph {
    std::vector<node> nodes;
};
struct emu_graph_exec {
    node_list nodes;
};

namespace {

emu_stream legacy; /* stream 0 */
std::vector<emu_stream *> streams{&legacy};

emu_stream *S(cudaStream_t s) { return s ? s : &legacy; }

void run_kernel(const emu::kernel_task &t);

void run_node(const node &n)
{
    switch (n.kind) {
    case NODE_KERNEL: run_kernel(n.k); break;
    case NODE_COPY: std::memmove(n.dst, n.src, n.bytes); break;
    case NODE_SET: std::memset(n.dst, n.value, n.bytes); break;
    }
}

void flush(emu_stream *s, uint64_t upto)
{
    while (s->done < upto) {
        op o = std::move(s->q.front());
        s->q.pop_front();
        if (o.kind == OP_WAIT) flush(o.ws, o.wt);
        else if (o.kind == OP_GRAPH)
            for (const node &n : *o.g) run_node(n);
        else run_node(o.n);
        s->done++;
    }
}

void flush_all()
{
    for (emu_stream *s : streams) flush(s, s->enqueued);
}

void enqueue(emu_stream *s, op &&o)
{
    if (s == &legacy) { /* the legacy stream waits for every other and runs at once */
        flush_all();
        s->q.push_back(std::move(o));
        s->enqueued++;
        flush(s, s->enqueued);
        return;
    }
    s->q.push_back(std::move(o));
    s->enqueued++;
}

/* Appends a node to the stream's queue, or to the graph it is capturing. */
cudaError_t submit(cudaStream_t st, node &&n)
{
    emu_stream *s = S(st);
    if (s->capture) {
        s->capture->nodes.push_back(std::move(n));
        return cudaSuccess;
    }
    op o{OP_NODE, std::move(n), nullptr, 0, nullptr};
    enqueue(s, std::move(o));
    return cudaSuccess;
}

bool any_capture()
{
    for (emu_stream *s : streams)
        if (s->capture) return true;
    return false;
}

/* A call that must not happen while a stream captures (it would synchronize). */
cudaError_t capture_forbidden(emu_stream *s)
{
    if (s->capture || (s == &legacy && any_capture())) {
        if (s->capture) s->capture_bad = true;
        return fail(cudaErrorStreamCaptureUnsupported);
    }
    return cudaSuccess;
}

/* ---- fibers ---- */

enum fstate { F_READY, F_BARRIER, F_WARP, F_DONE };

struct pool;
struct fiber {
    emu::thread_view view;
    void *jb[5];
    char *stack;
    size_t stack_size;
    fstate state;
    int bar_kind, pred, result;
    int wop, warg, wwidth;
    unsigned wmask;
    uint64_t wval, wres;
    pool *owner;
    void *asan_fake;
};

struct pool {
    std::vector<fiber *> fibers;
    void *sched_jb[5];
    const emu::kernel_task *task = nullptr;
    unsigned char *smem = nullptr;
    size_t smem_cap = 0;
    const void *sched_bottom = nullptr;
    size_t sched_size = 0;
    void *sched_fake = nullptr;
    ucontext_t boot_uc, boot_back;
    uint64_t loads = 0, stores = 0;       /* bytes accessed in this launch (while counting) */
    std::vector<unsigned> ready;          /* threads that can run */
    std::vector<unsigned> warp_arrived;   /* per warp: lanes waiting at a warp operation */
    unsigned at_barrier = 0, done = 0;
};

#ifdef EMU_ASAN
const size_t STACK = 512 * 1024;
#else
const size_t STACK = 128 * 1024;
#endif

std::mutex pools_lock;
std::vector<pool *> all_pools; /* never freed: kept reachable for LeakSanitizer */
thread_local pool *tls_pool;
thread_local fiber *boot_fiber;

/* The switches must stay opaque calls: the compiler may not assume that registers survive them
 * the way a plain callee leaves them (interprocedural register allocation would). */
#if defined(__clang__)
#define SWITCH_FN __attribute__((noinline))
#else
#define SWITCH_FN __attribute__((noipa))
#endif

/* Not instrumented: ASan would call __asan_handle_no_return before the jump, which unpoisons the
 * stack left behind (a system call each time) - but no frame is left behind here: the fiber or
 * scheduler jumped from resumes in that very frame, and ASan hears of each switch anyway. */
#ifdef EMU_ASAN
#define NO_ASAN __attribute__((no_sanitize_address))
#else
#define NO_ASAN
#endif
SWITCH_FN NO_ASAN void jump(void **jb) { __builtin_longjmp(jb, 1); }

SWITCH_FN void fiber_main()
{
    fiber *self = boot_fiber;
    pool *p = self->owner;
    FINISH_SWITCH(nullptr, &p->sched_bottom, &p->sched_size);
    if (__builtin_setjmp(self->jb) == 0) {
        START_SWITCH(&self->asan_fake, p->sched_bottom, p->sched_size);
        swapcontext(&p->boot_uc, &p->boot_back); /* back to the creator; resumed by jump(self->jb) */
    }
    FINISH_SWITCH(self->asan_fake, nullptr, nullptr);
    for (;;) {
        self->owner->task->body();
        self->state = F_DONE;
        START_SWITCH(&self->asan_fake, p->sched_bottom, p->sched_size);
        if (__builtin_setjmp(self->jb) == 0) jump(p->sched_jb);
        FINISH_SWITCH(self->asan_fake, nullptr, nullptr);
    }
}

fiber *new_fiber(pool *p)
{
    fiber *f = new fiber();
    const size_t page = (size_t)sysconf(_SC_PAGESIZE);
    char *m = (char *)mmap(nullptr, STACK + page, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (m == MAP_FAILED) die("out of memory for a fiber stack");
    mprotect(m, page, PROT_NONE); /* a guard page below: an overflow faults */
    f->stack = m + page;
    f->stack_size = STACK;
    f->owner = p;
    f->state = F_DONE;
    getcontext(&p->boot_uc);
    p->boot_uc.uc_stack.ss_sp = f->stack;
    p->boot_uc.uc_stack.ss_size = f->stack_size;
    p->boot_uc.uc_link = nullptr;
    makecontext(&p->boot_uc, fiber_main, 0);
    boot_fiber = f;
    START_SWITCH(&p->sched_fake, f->stack, f->stack_size);
    swapcontext(&p->boot_back, &p->boot_uc);
    FINISH_SWITCH(p->sched_fake, nullptr, nullptr);
    return f;
}

pool *this_pool()
{
    if (!tls_pool) {
        tls_pool = new pool();
        std::lock_guard<std::mutex> g(pools_lock);
        all_pools.push_back(tls_pool);
    }
    return tls_pool;
}

fiber *running_fiber()
{
    fiber *f = reinterpret_cast<fiber *>(emu::cur);
    if (!f) die("a device function was called outside a kernel");
    return f;
}

/* From a fiber: back to the block's scheduler until released. */
SWITCH_FN void yield(fiber *self)
{
    pool *p = self->owner;
    emu::cur = nullptr;
    START_SWITCH(&self->asan_fake, p->sched_bottom, p->sched_size);
    if (__builtin_setjmp(self->jb) == 0) jump(p->sched_jb);
    FINISH_SWITCH(self->asan_fake, nullptr, nullptr);
    emu::cur = &self->view;
}

SWITCH_FN void resume(pool *p, fiber *f)
{
    emu::cur = &f->view;
    START_SWITCH(&p->sched_fake, f->stack, f->stack_size);
    if (__builtin_setjmp(p->sched_jb) == 0) jump(f->jb);
    FINISH_SWITCH(p->sched_fake, nullptr, nullptr);
    emu::cur = nullptr;
}

const char *state_name(const fiber *f)
{
    switch (f->state) {
    case F_READY: return "running";
    case F_BARRIER: return "at a block barrier";
    case F_WARP: return "at a warp operation";
    default: return "exited";
    }
}

[[noreturn]] void stuck(pool *p, unsigned n, const char *why)
{
    std::fprintf(stderr, "cuda emulation: kernel %s, block (%u,%u,%u): %s\n", p->task->name,
                 p->fibers[0]->view.bid.x, p->fibers[0]->view.bid.y, p->fibers[0]->view.bid.z, why);
    for (unsigned i = 0, j; i < n; i = j) { /* runs of threads in the same state */
        for (j = i + 1; j < n && p->fibers[j]->state == p->fibers[i]->state; j++) {
        }
        std::fprintf(stderr, "  threads %u-%u: %s\n", i, j - 1, state_name(p->fibers[i]));
    }
    std::abort();
}

/* A warp operation completes when every lane its mask names has arrived at it: each lane gets
 * its result and runs again. */
void warp_arrived(pool *p, unsigned n, unsigned idx)
{
    const unsigned w0 = idx / 32 * 32, l = idx % 32;
    fiber *a = p->fibers[idx];
    const unsigned m = a->wmask;
    if (!(m >> l & 1)) stuck(p, n, "a lane called a warp operation with a mask that leaves itself out");
    p->warp_arrived[idx / 32] |= 1u << l;
    if ((p->warp_arrived[idx / 32] & m) != m) return;
    uint64_t ballot = 0;
    for (unsigned k = 0; k < 32; k++) {
        if (!(m >> k & 1)) continue;
        if (w0 + k >= n) stuck(p, n, "a warp operation's mask names lanes the block does not have");
        const fiber *b = p->fibers[w0 + k];
        if (b->wop != a->wop || b->wmask != m || b->wwidth != a->wwidth)
            stuck(p, n, "lanes named in a warp operation's mask met at different warp operations");
        if (b->wval) ballot |= 1ull << k;
    }
    for (unsigned k = 0; k < 32; k++) {
        if (!(m >> k & 1)) continue;
        fiber *b = p->fibers[w0 + k];
        const int width = b->wwidth, seg = (int)k / width * width, pos = (int)k - seg;
        int src = (int)k;
        switch (b->wop) {
        case emu::WARP_SHFL: src = seg + b->warg % width; break;
        case emu::WARP_SHFL_DOWN: src = pos + b->warg < width ? (int)k + b->warg : (int)k; break;
        case emu::WARP_SHFL_UP: src = pos - b->warg >= 0 ? (int)k - b->warg : (int)k; break;
        case emu::WARP_SHFL_XOR: src = (pos ^ b->warg) < width ? seg + (pos ^ b->warg) : (int)k; break;
        default: break;
        }
        if (b->wop == emu::WARP_BALLOT) b->wres = ballot;
        else if (b->wop == emu::WARP_SYNC) b->wres = 0;
        else {
            if (!(m >> src & 1)) stuck(p, n, "a shuffle read a lane outside its mask");
            b->wres = p->fibers[w0 + (unsigned)src]->wval;
        }
    }
    p->warp_arrived[idx / 32] &= ~m;
    for (unsigned k = 0; k < 32; k++)
        if (m >> k & 1) {
            p->fibers[w0 + k]->state = F_READY;
            p->ready.push_back(w0 + k);
        }
}

/* A block barrier completes when every thread of the block waits at it. */
void barrier_arrived(pool *p, unsigned n)
{
    if (p->at_barrier + p->done != n) return;
    if (p->done) stuck(p, n, "a barrier that threads which already exited never reach");
    const int kind = p->fibers[0]->bar_kind;
    int r = kind == 2 ? 1 : 0;
    for (unsigned i = 0; i < n; i++) {
        const fiber *f = p->fibers[i];
        if (f->bar_kind != kind) stuck(p, n, "threads wait at different kinds of barrier");
        if (kind == 1) r |= f->pred != 0;
        else if (kind == 2) r &= f->pred != 0;
        else if (kind == 3) r += f->pred != 0;
    }
    for (unsigned i = 0; i < n; i++) {
        p->fibers[i]->result = r;
        p->fibers[i]->state = F_READY;
        p->ready.push_back(n - 1 - i);
    }
    p->at_barrier = 0;
}

/* Runs a block: each thread until it waits, releasing threads as their barrier or warp operation
 * completes; any thread left waiting when none can run is a bug in the kernel. */
void run_block(pool *p, const emu::kernel_task &t, uint3 bid)
{
    const unsigned n = t.block.x * t.block.y * t.block.z;
    while (p->fibers.size() < n) p->fibers.push_back(new_fiber(p));
    p->task = &t;
    if (t.smem > p->smem_cap) {
        std::free(p->smem);
        p->smem = (unsigned char *)std::malloc(t.smem);
        if (!p->smem) die("out of memory for shared memory");
        p->smem_cap = t.smem;
    }
    if (t.smem) std::memset(p->smem, 0xff, t.smem);
    p->ready.clear();
    for (unsigned i = 0; i < n; i++) {
        fiber *f = p->fibers[i];
        f->view.tid = uint3{i % t.block.x, i / t.block.x % t.block.y, i / (t.block.x * t.block.y)};
        f->view.bid = bid;
        f->view.bdim = t.block;
        f->view.gdim = t.grid;
        f->state = F_READY;
        p->ready.push_back(n - 1 - i); /* thread 0 first */
    }
    p->warp_arrived.assign((n + 31) / 32, 0);
    p->at_barrier = p->done = 0;
    while (!p->ready.empty()) {
        const unsigned i = p->ready.back();
        p->ready.pop_back();
        fiber *f = p->fibers[i];
        resume(p, f);
        if (f->state == F_DONE) {
            p->done++;
            if (p->at_barrier) barrier_arrived(p, n);
        } else if (f->state == F_BARRIER) {
            p->at_barrier++;
            barrier_arrived(p, n);
        } else if (f->state == F_WARP) {
            warp_arrived(p, n, i);
        } else {
            die("a fiber came back without waiting");
        }
    }
    if (p->done != n) stuck(p, n, "no thread can go on (a barrier or warp operation that not all threads reach)");
    p->task = nullptr;
}

/* ---- byte counting ---- */

std::vector<alloc *> touched_allocs;

void count_launch(kstats &ks)
{
    uint64_t r = 0, w = 0;
    for (auto &kv : allocs) {
        alloc &a = kv.second;
        if (!a.touched) continue;
        for (uint64_t x : a.rbits) r += (uint64_t)__builtin_popcountll(x);
        for (uint64_t x : a.wbits) w += (uint64_t)__builtin_popcountll(x);
        std::fill(a.rbits.begin(), a.rbits.end(), 0);
        std::fill(a.wbits.begin(), a.wbits.end(), 0);
        a.touched = 0;
    }
    ks.read += r;
    ks.written += w;
    std::lock_guard<std::mutex> g(pools_lock);
    for (pool *p : all_pools) {
        ks.loads += p->loads;
        ks.stores += p->stores;
        p->loads = p->stores = 0;
    }
    ks.counted++;
}

void run_kernel(const emu::kernel_task &t)
{
    auto it = kernel_index.find(t.name);
    if (it == kernel_index.end()) {
        it = kernel_index.emplace(t.name, kernel_stats.size()).first;
        kernel_stats.push_back(kstats{t.name});
    }
    kstats &ks = kernel_stats[it->second];
    ks.launches++;
    ks.threads += (uint64_t)t.grid.x * t.grid.y * t.grid.z * t.block.x * t.block.y * t.block.z;
    counters.kernel_launches++;
    const int count = emu::counting;
    if (count)
        for (auto &kv : allocs) {
            const size_t words = (kv.second.bytes + 63) / 64;
            if (kv.second.rbits.size() != words) {
                kv.second.rbits.assign(words, 0);
                kv.second.wbits.assign(words, 0);
            }
        }
    const long blocks = (long)t.grid.x * t.grid.y * t.grid.z;
#pragma omp parallel for schedule(dynamic, 1) if (blocks > 1)
    for (long b = 0; b < blocks; b++) {
        const uint3 bid{(unsigned)(b % t.grid.x), (unsigned)(b / t.grid.x % t.grid.y),
                        (unsigned)(b / ((long)t.grid.x * t.grid.y))};
        run_block(this_pool(), t, bid);
    }
    if (count) count_launch(ks);
}

} // namespace

/* ---- device-side entry points ---- */

namespace emu {

void syncthreads() { (void)syncthreads_reduce(0, 0); }

int syncthreads_reduce(int kind, int pred)
{
    fiber *f = running_fiber();
    f->state = F_BARRIER;
    f->bar_kind = kind;
    f->pred = pred;
    yield(f);
    return f->result;
}

uint64_t warp_op(int op, unsigned mask, uint64_t value, int arg, int width)
{
    fiber *f = running_fiber();
    if (width <= 0 || width > 32 || (width & (width - 1))) die("a warp operation's width is not a power of two up to 32");
    f->state = F_WARP;
    f->wop = op;
    f->wmask = mask;
    f->wval = value;
    f->warg = arg;
    f->wwidth = width;
    yield(f);
    return f->wres;
}

void *dynamic_shared()
{
    pool *p = running_fiber()->owner;
    return p->smem;
}

void touch(const void *ptr, size_t bytes, int write)
{
    uintptr_t base;
    alloc *a = find(ptr, bytes, &base);
    if (!a) die("a kernel touched memory outside every device allocation");
    pool *p = running_fiber()->owner;
    (write ? p->stores : p->loads) += bytes;
    std::vector<uint64_t> &bits = write ? a->wbits : a->rbits;
    const uintptr_t off = (uintptr_t)ptr - base;
    for (size_t k = 0; k < bytes; k++)
        __atomic_fetch_or(&bits[(off + k) / 64], 1ull << ((off + k) % 64), __ATOMIC_RELAXED);
    __atomic_store_n(&a->touched, 1, __ATOMIC_RELAXED);
}

void enqueue_kernel(cudaStream_t st, kernel_task &&t)
{
    emu_stream *s = S(st);
    if (dead) {
        last_error = dead;
        return;
    }
    const unsigned threads = t.block.x * t.block.y * t.block.z;
    cudaError_t e = cudaSuccess;
    if (threads == 0 || threads > 1024 || t.block.z > 64 || t.grid.x == 0 || t.grid.y == 0 || t.grid.z == 0 ||
        t.grid.y > 65535 || t.grid.z > 65535)
        e = cudaErrorInvalidConfiguration;
    else if (t.smem > 48 * 1024)
        e = cudaErrorInvalidValue; /* more needs cudaFuncSetAttribute, which the backend does not use */
    if (e != cudaSuccess) {
        last_error = e;
        if (s->capture) s->capture_bad = true;
        return;
    }
    node n{NODE_KERNEL, std::move(t), nullptr, nullptr, 0, 0, cudaMemcpyDefault};
    submit(st, std::move(n));
}

} // namespace emu

/* ---- host API ---- */

const char *cudaGetErrorName(cudaError_t e)
{
    switch (e) {
#define N(x)                                                                                           \
    case x: return #x;
        N(cudaSuccess) N(cudaErrorInvalidValue) N(cudaErrorMemoryAllocation) N(cudaErrorInitializationError)
        N(cudaErrorInvalidConfiguration) N(cudaErrorNoDevice) N(cudaErrorInvalidDevice) N(cudaErrorECCUncorrectable)
        N(cudaErrorInvalidResourceHandle) N(cudaErrorIllegalState) N(cudaErrorNotReady) N(cudaErrorIllegalAddress)
        N(cudaErrorLaunchOutOfResources) N(cudaErrorLaunchTimeout) N(cudaErrorAssert) N(cudaErrorHardwareStackError)
        N(cudaErrorIllegalInstruction) N(cudaErrorMisalignedAddress) N(cudaErrorInvalidAddressSpace)
        N(cudaErrorInvalidPc) N(cudaErrorLaunchFailure) N(cudaErrorStreamCaptureUnsupported)
        N(cudaErrorStreamCaptureInvalidated) N(cudaErrorStreamCaptureUnjoined) N(cudaErrorStreamCaptureIsolation)
        N(cudaErrorCapturedEvent) N(cudaErrorStreamCaptureWrongThread) N(cudaErrorGraphExecUpdateFailure)
        N(cudaErrorUnknown)
#undef N
    }
    return "cudaErrorUnknown";
}
const char *cudaGetErrorString(cudaError_t e)
{
    switch (e) {
    case cudaSuccess: return "no error";
    case cudaErrorMemoryAllocation: return "out of memory";
    case cudaErrorInvalidValue: return "invalid argument";
    case cudaErrorInvalidConfiguration: return "invalid configuration argument";
    case cudaErrorIllegalAddress: return "an illegal memory access was encountered";
    case cudaErrorStreamCaptureUnsupported: return "operation not permitted when stream is capturing";
    case cudaErrorStreamCaptureInvalidated: return "operation failed due to a previous error during capture";
    case cudaErrorGraphExecUpdateFailure: return "the graph update was not performed";
    default: return cudaGetErrorName(e);
    }
}
cudaError_t cudaGetLastError(void)
{
    const cudaError_t e = last_error;
    last_error = cudaSuccess;
    return e;
}
cudaError_t cudaPeekAtLastError(void) { return last_error; }

cudaError_t cudaGetDeviceCount(int *count)
{
    if (!count) return fail(cudaErrorInvalidValue);
    *count = 1;
    return cudaSuccess;
}
cudaError_t cudaGetDevice(int *dev)
{
    if (!dev) return fail(cudaErrorInvalidValue);
    *dev = 0;
    return dead ? fail(dead) : cudaSuccess;
}
cudaError_t cudaSetDevice(int dev) { return dev == 0 ? cudaSuccess : fail(cudaErrorInvalidDevice); }
static int host_threads()
{
#ifdef _OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}
cudaError_t cudaGetDeviceProperties(cudaDeviceProp *prop, int dev)
{
    if (!prop || dev != 0) return fail(cudaErrorInvalidValue);
    std::memset(prop, 0, sizeof *prop);
    std::snprintf(prop->name, sizeof prop->name, "CPU imitation of CUDA (tests/emu)");
    prop->major = 9;
    prop->minor = 0;
    prop->multiProcessorCount = host_threads();
    prop->totalGlobalMem = (size_t)80 << 30;
    return cudaSuccess;
}
cudaError_t cudaDeviceGetAttribute(int *value, cudaDeviceAttr attr, int dev)
{
    if (!value || dev != 0) return fail(cudaErrorInvalidValue);
    /* No memory clock or bus: the imitation has no bandwidth to model. */
    *value = attr == cudaDevAttrMultiProcessorCount ? host_threads() : 0;
    return cudaSuccess;
}
cudaError_t cudaDeviceSynchronize(void)
{
    if (dead) return fail(dead);
    if (any_capture()) return fail(cudaErrorStreamCaptureUnsupported);
    counters.host_waits++;
    flush_all();
    return cudaSuccess;
}

cudaError_t cudaMalloc(void **p, size_t bytes)
{
    if (any_capture()) return fail(cudaErrorStreamCaptureUnsupported);
    return allocate(p, bytes, false);
}
cudaError_t cudaMallocHost(void **p, size_t bytes) { return allocate(p, bytes, true); }
cudaError_t cudaHostAlloc(void **p, size_t bytes, unsigned flags)
{
    (void)flags;
    return allocate(p, bytes, true);
}
cudaError_t cudaFree(void *p)
{
    if (any_capture()) return fail(cudaErrorStreamCaptureUnsupported);
    flush_all(); /* cudaFree waits for the device */
    return release(p, false);
}
cudaError_t cudaFreeHost(void *p)
{
    flush_all();
    return release(p, true);
}

static cudaError_t copy(void *dst, const void *src, size_t bytes, cudaMemcpyKind kind, cudaStream_t st, bool async)
{
    if (dead) return fail(dead);
    if (!bytes) return cudaSuccess;
    emu_stream *s = S(st);
    alloc *ad = find(dst, bytes), *as = find(src, bytes);
    const bool dev_dst = ad && !ad->pinned, dev_src = as && !as->pinned;
    if (kind == cudaMemcpyDefault)
        kind = dev_src ? (dev_dst ? cudaMemcpyDeviceToDevice : cudaMemcpyDeviceToHost)
                       : (dev_dst ? cudaMemcpyHostToDevice : cudaMemcpyHostToHost);
    const bool want_dst = kind == cudaMemcpyHostToDevice || kind == cudaMemcpyDeviceToDevice;
    const bool want_src = kind == cudaMemcpyDeviceToHost || kind == cudaMemcpyDeviceToDevice;
    if (want_dst != dev_dst || want_src != dev_src) return fail(cudaErrorInvalidValue);
    /* Host memory the runtime did not allocate is pageable: the copy happens before the call
     * returns, after the work queued before it. */
    const void *host = kind == cudaMemcpyHostToDevice ? src : kind == cudaMemcpyDeviceToHost ? dst : nullptr;
    const bool pageable = host && !find(host, bytes);
    if (kind == cudaMemcpyHostToDevice) counters.bytes_h2d += bytes, counters.copies_h2d++;
    if (kind == cudaMemcpyDeviceToHost) counters.bytes_d2h += bytes, counters.copies_d2h++;
    if (kind == cudaMemcpyDeviceToDevice) counters.bytes_d2d += bytes;
    if (!async || pageable) {
        cudaError_t e = capture_forbidden(s);
        if (e != cudaSuccess) return e;
        if (async) counters.pageable_async_copies++;
        counters.host_waits++;
        flush(s, s->enqueued);
        if (!async) flush_all();
        std::memmove(dst, src, bytes);
        return cudaSuccess;
    }
    node n{NODE_COPY, {}, dst, src, bytes, 0, kind};
    return submit(st, std::move(n));
}
cudaError_t cudaMemcpy(void *dst, const void *src, size_t bytes, cudaMemcpyKind kind)
{
    return copy(dst, src, bytes, kind, 0, false);
}
cudaError_t cudaMemcpyAsync(void *dst, const void *src, size_t bytes, cudaMemcpyKind kind, cudaStream_t s)
{
    return copy(dst, src, bytes, kind, s, true);
}
cudaError_t cudaMemsetAsync(void *dst, int value, size_t bytes, cudaStream_t s)
{
    if (dead) return fail(dead);
    alloc *a = find(dst, bytes);
    if (bytes && (!a || a->pinned)) return fail(cudaErrorInvalidValue);
    node n{NODE_SET, {}, dst, nullptr, bytes, value, cudaMemcpyDefault};
    return submit(s, std::move(n));
}
cudaError_t cudaMemset(void *dst, int value, size_t bytes)
{
    const cudaError_t e = cudaMemsetAsync(dst, value, bytes, 0);
    return e;
}

cudaError_t cudaStreamCreate(cudaStream_t *s) { return cudaStreamCreateWithFlags(s, 0); }
cudaError_t cudaStreamCreateWithFlags(cudaStream_t *s, unsigned flags)
{
    (void)flags;
    if (!s) return fail(cudaErrorInvalidValue);
    if (dead) return fail(dead);
    *s = new emu_stream();
    streams.push_back(*s);
    return cudaSuccess;
}
cudaError_t cudaStreamDestroy(cudaStream_t s)
{
    if (!s) return fail(cudaErrorInvalidResourceHandle);
    flush(s, s->enqueued);
    for (size_t i = 0; i < streams.size(); i++)
        if (streams[i] == s) streams.erase(streams.begin() + (long)i);
    delete s->capture;
    delete s;
    return cudaSuccess;
}
cudaError_t cudaStreamSynchronize(cudaStream_t st)
{
    if (dead) return fail(dead);
    emu_stream *s = S(st);
    cudaError_t e = capture_forbidden(s);
    if (e != cudaSuccess) return e;
    counters.host_waits++;
    if (s == &legacy) flush_all();
    else flush(s, s->enqueued);
    return cudaSuccess;
}
cudaError_t cudaStreamQuery(cudaStream_t st) { return cudaStreamSynchronize(st); }
cudaError_t cudaStreamWaitEvent(cudaStream_t st, cudaEvent_t e, unsigned flags)
{
    (void)flags;
    if (!e) return fail(cudaErrorInvalidResourceHandle);
    if (dead) return fail(dead);
    emu_stream *s = S(st);
    if (!e->s) return cudaSuccess; /* never recorded: nothing to wait for */
    if (s->capture) {              /* an event from outside the capture */
        s->capture_bad = true;
        return fail(cudaErrorStreamCaptureIsolation);
    }
    op o{OP_WAIT, node{}, e->s, e->target, nullptr};
    enqueue(s, std::move(o));
    return cudaSuccess;
}
cudaError_t cudaEventCreate(cudaEvent_t *e) { return cudaEventCreateWithFlags(e, 0); }
cudaError_t cudaEventCreateWithFlags(cudaEvent_t *e, unsigned flags)
{
    (void)flags;
    if (!e) return fail(cudaErrorInvalidValue);
    *e = new emu_event();
    return cudaSuccess;
}
cudaError_t cudaEventDestroy(cudaEvent_t e)
{
    delete e;
    return cudaSuccess;
}
/* The checks of a call that takes a handle and must not be captured (the backend records no events
 * and launches no graphs inside a capture): the stream, or NULL after recording the error. */
static emu_stream *uncaptured(const void *handle, cudaStream_t st)
{
    emu_stream *s = S(st);
    const cudaError_t e = !handle ? cudaErrorInvalidResourceHandle : dead ? dead
                          : s->capture ? cudaErrorStreamCaptureUnsupported : cudaSuccess;
    if (s->capture) s->capture_bad = true;
    if (e != cudaSuccess) fail(e);
    return e == cudaSuccess ? s : nullptr;
}
cudaError_t cudaEventRecord(cudaEvent_t e, cudaStream_t st)
{
    emu_stream *s = uncaptured(e, st);
    if (!s) return last_error;
    e->s = s;
    e->target = s->enqueued;
    return cudaSuccess;
}
cudaError_t cudaEventSynchronize(cudaEvent_t e)
{
    if (!e) return fail(cudaErrorInvalidResourceHandle);
    if (dead) return fail(dead);
    counters.host_waits++;
    if (e->s) flush(e->s, e->target);
    return cudaSuccess;
}
cudaError_t cudaEventQuery(cudaEvent_t e)
{
    if (!e) return fail(cudaErrorInvalidResourceHandle);
    if (e->s) flush(e->s, e->target); /* lazily: what a query finds pending, runs now */
    return cudaSuccess;
}

cudaError_t cudaEventElapsedTime(float *ms, cudaEvent_t a, cudaEvent_t b)
{
    if (!ms || !a || !b) return fail(cudaErrorInvalidValue);
    cudaEventSynchronize(b);
    *ms = 1.0f;
    return cudaSuccess;
}

cudaError_t cudaStreamBeginCapture(cudaStream_t st, cudaStreamCaptureMode mode)
{
    (void)mode;
    if (dead) return fail(dead);
    emu_stream *s = S(st);
    if (s == &legacy || s->capture) return fail(cudaErrorIllegalState);
    s->capture = new emu_graph();
    s->capture_bad = false;
    return cudaSuccess;
}
cudaError_t cudaStreamEndCapture(cudaStream_t st, cudaGraph_t *g)
{
    emu_stream *s = S(st);
    if (!g) return fail(cudaErrorInvalidValue);
    *g = nullptr;
    if (!s->capture) return fail(cudaErrorIllegalState);
    emu_graph *graph = s->capture;
    s->capture = nullptr;
    counters.captures++;
    if (s->capture_bad) {
        delete graph;
        return fail(cudaErrorStreamCaptureInvalidated);
    }
    *g = graph;
    return cudaSuccess;
}
cudaError_t cudaGraphDestroy(cudaGraph_t g)
{
    delete g;
    return cudaSuccess;
}
cudaError_t cudaGraphInstantiate(cudaGraphExec_t *exec, cudaGraph_t g, unsigned long long flags)
{
    (void)flags;
    if (!exec || !g) return fail(cudaErrorInvalidValue);
    if (dead) return fail(dead);
    *exec = new emu_graph_exec{std::make_shared<const std::vector<node>>(g->nodes)};
    counters.graph_instantiations++;
    return cudaSuccess;
}
cudaError_t cudaGraphExecUpdate(cudaGraphExec_t exec, cudaGraph_t g, cudaGraphExecUpdateResultInfo *info)
{
    if (!exec || !g || !info) return fail(cudaErrorInvalidValue);
    info->errorNode = info->errorFromNode = nullptr;
    info->result = cudaGraphExecUpdateSuccess;
    const std::vector<node> &a = *exec->nodes, &b = g->nodes;
    if (a.size() != b.size()) info->result = cudaGraphExecUpdateErrorTopologyChanged;
    for (size_t i = 0; info->result == cudaGraphExecUpdateSuccess && i < a.size(); i++) {
        if (a[i].kind != b[i].kind) info->result = cudaGraphExecUpdateErrorNodeTypeChanged;
        else if (a[i].kind == NODE_KERNEL && a[i].k.fn != b[i].k.fn) info->result = cudaGraphExecUpdateErrorFunctionChanged;
        else if (a[i].kind == NODE_COPY && a[i].ckind != b[i].ckind) info->result = cudaGraphExecUpdateErrorParametersChanged;
    }
    if (info->result != cudaGraphExecUpdateSuccess) return fail(cudaErrorGraphExecUpdateFailure);
    exec->nodes = std::make_shared<const std::vector<node>>(b); /* launches already queued keep theirs */
    counters.graph_updates++;
    return cudaSuccess;
}
cudaError_t cudaGraphExecDestroy(cudaGraphExec_t exec)
{
    delete exec;
    return cudaSuccess;
}
cudaError_t cudaGraphLaunch(cudaGraphExec_t exec, cudaStream_t st)
{
    emu_stream *s = uncaptured(exec, st);
    if (!s) return last_error;
    counters.graph_launches++;
    op o{OP_GRAPH, node{}, nullptr, 0, exec->nodes};
    enqueue(s, std::move(o));
    return cudaSuccess;
}

/* ---- emu.h ---- */

extern "C" {
void emu_get_counters(emu_counters *out) { *out = counters; }
void emu_reset_counters(void)
{
    const uint64_t dev = counters.device_bytes, pin = counters.pinned_bytes;
    std::memset(&counters, 0, sizeof counters);
    counters.device_bytes = counters.device_bytes_peak = dev;
    counters.pinned_bytes = pin;
}
void emu_fail_alloc_after(int k) { fail_alloc = k; }
void emu_fail_device(int err) { dead = (cudaError_t)err; }
void emu_count_bytes(int on)
{
    flush_all();
    emu::counting = on;
}
int emu_kernel_stats_get(emu_kernel_stats *out, int cap)
{
    for (int i = 0; i < cap && i < (int)kernel_stats.size(); i++) {
        std::snprintf(out[i].name, sizeof out[i].name, "%s", kernel_stats[(size_t)i].name.c_str());
        out[i].launches = kernel_stats[(size_t)i].launches;
        out[i].threads = kernel_stats[(size_t)i].threads;
        out[i].read = kernel_stats[(size_t)i].read;
        out[i].written = kernel_stats[(size_t)i].written;
        out[i].loads = kernel_stats[(size_t)i].loads;
        out[i].stores = kernel_stats[(size_t)i].stores;
        out[i].counted = kernel_stats[(size_t)i].counted;
    }
    return (int)kernel_stats.size();
}
void emu_kernel_stats_reset(void)
{
    kernel_stats.clear();
    kernel_index.clear();
}
}
