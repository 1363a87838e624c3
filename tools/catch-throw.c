// A diagnostic preload for suite runs (tools/catch-throw): every C++ exception thrown in the
// process is reported on stderr with its type and a backtrace before it is thrown on. A clean
// run throws none (checked on the whole suite: docs/decisions.md, "... a foreign exception
// hunted"), so any report names the library that threw; one that reaches a Vulkan call from
// Rust aborts the test with "Rust cannot catch foreign exceptions", and nextest keeps this
// report in its output.
// The interposition works for throws that reach __cxa_throw through the dynamic linker (the
// validation layer, LLVM, SPIRV-Tools and libstdc++'s own __throw_* helpers all call it so).
//
// It also reports the fatal signals (SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGABRT) with the thread,
// the faulting address and a backtrace, then dies of the same signal as before: the project's
// rare unexplained SIGSEGV (docs/decisions.md, "A crash seen on the way") left nothing that
// names the library or thread it came from, and glibc's heap checks end in SIGABRT. The handler
// is installed when the library loads, before Rust's runtime starts: Rust's own SIGSEGV handler
// (which tells a stack overflow from other faults) is installed only where none is, so under this
// preload a stack overflow is reported as a SIGSEGV with its backtrace (on the main thread,
// which gets an alternate stack here; a spawned thread's overflow dies unreported, as any
// SIGSEGV did before).
#define _GNU_SOURCE
#include <dlfcn.h>
#include <execinfo.h>
#include <fcntl.h>
#include <signal.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>
#include <sys/syscall.h>
#include <unistd.h>

typedef void (*throw_fn)(void *, void *, void (*)(void *));

void __cxa_throw(void *obj, void *tinfo, void (*dest)(void *)) {
    static throw_fn real;
    if (!real) real = (throw_fn)dlsym(RTLD_NEXT, "__cxa_throw");
    // std::type_info is {vtable, const char *name}: the mangled name of the thrown type.
    const char *name = tinfo ? ((const char *const *)tinfo)[1] : "?";
    void *frames[64];
    int n = backtrace(frames, 64);
    // stderr (nextest keeps it with the test), and the file CATCH_THROW_LOG names if set (one
    // place to look after a whole suite).
    const char *log = getenv("CATCH_THROW_LOG");
    int fds[2] = {2, log ? open(log, O_WRONLY | O_CREAT | O_APPEND, 0644) : -1};
    for (int i = 0; i < 2; ++i) {
        if (fds[i] < 0) continue;
        dprintf(fds[i], "catch-throw: pid %d throws a C++ exception of type %s from:\n", (int)getpid(), name);
        backtrace_symbols_fd(frames, n, fds[i]);
    }
    if (fds[1] >= 0) close(fds[1]);
    real(obj, tinfo, dest);
    __builtin_unreachable();
}

// The log's path, read once at load (getenv is not for signal handlers).
static const char *signal_log;

static const char *signal_name(int sig) {
    switch (sig) {
    case SIGSEGV: return "SIGSEGV";
    case SIGBUS: return "SIGBUS";
    case SIGILL: return "SIGILL";
    case SIGFPE: return "SIGFPE";
    case SIGABRT: return "SIGABRT";
    default: return "?";
    }
}

static void report_signal(int sig, siginfo_t *info, void *ctx) {
    (void)ctx;
    void *frames[64];
    int n = backtrace(frames, 64);
    int fds[2] = {2, signal_log ? open(signal_log, O_WRONLY | O_CREAT | O_APPEND, 0644) : -1};
    for (int i = 0; i < 2; ++i) {
        if (fds[i] < 0) continue;
        dprintf(fds[i], "catch-throw: pid %d thread %ld dies of %s (address %p) from:\n", (int)getpid(),
                (long)syscall(SYS_gettid), signal_name(sig), info ? info->si_addr : NULL);
        backtrace_symbols_fd(frames, n, fds[i]);
    }
    if (fds[1] >= 0) close(fds[1]);
    // Die of the same signal: the default action, raised again (a fault re-faults on return).
    signal(sig, SIG_DFL);
    raise(sig);
}

__attribute__((constructor)) static void install_signal_reports(void) {
    signal_log = getenv("CATCH_THROW_LOG");
    // backtrace() loads libgcc_s on its first call (which allocates): once here, not in a
    // handler that may run with the heap broken.
    void *warm[1];
    backtrace(warm, 1);
    static char altstack[1 << 16];
    stack_t ss = {.ss_sp = altstack, .ss_size = sizeof altstack, .ss_flags = 0};
    sigaltstack(&ss, NULL);
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_sigaction = report_signal;
    sa.sa_flags = SA_SIGINFO | SA_ONSTACK | SA_RESETHAND;
    sigemptyset(&sa.sa_mask);
    int sigs[] = {SIGSEGV, SIGBUS, SIGILL, SIGFPE, SIGABRT};
    for (unsigned i = 0; i < sizeof sigs / sizeof sigs[0]; ++i) sigaction(sigs[i], &sa, NULL);
}
