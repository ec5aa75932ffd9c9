/* Test double of a full disk, preloaded into the recorder by recording_fault.test
 * (LD_PRELOAD=librig_test_write_fault.so; C linkage, replacing stdio's own): files opened for
 * writing under $RIG_FAULT_DIR share a quota of $RIG_FAULT_QUOTA_BYTES. The quota counts what the
 * folder already holds when a process first writes there, plus what it writes, so a recorder
 * started again finds the folder as full as the one before left it. Past the quota, fwrite writes
 * nothing and fails with ENOSPC, as stdio does on a full file system; reads and every other file
 * are untouched. */
#include <dirent.h>
#include <dlfcn.h>
#include <errno.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

extern "C" {

#define MAX_TRACKED 64

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static FILE* tracked[MAX_TRACKED] = {};
static long long used = -1; /* bytes in the folder plus bytes written since; -1 = not read yet */

static const char* faultDir(void) { return getenv("RIG_FAULT_DIR"); }

static long long quota(void) {
  const char* q = getenv("RIG_FAULT_QUOTA_BYTES");
  return q ? atoll(q) : -1;
}

static int underDir(const char* path) {
  const char* d = faultDir();
  size_t n;
  if (!d || !path) return 0;
  n = strlen(d);
  return strncmp(path, d, n) == 0 && (path[n] == '/' || path[n] == '\0');
}

static long long folderBytes(const char* dir) {
  long long total = 0;
  struct dirent* e;
  DIR* d = dir ? opendir(dir) : NULL;
  if (!d) return 0;
  while ((e = readdir(d)) != NULL) {
    char p[4096];
    struct stat st;
    snprintf(p, sizeof p, "%s/%s", dir, e->d_name);
    if (stat(p, &st) == 0 && S_ISREG(st.st_mode)) total += st.st_size;
  }
  closedir(d);
  return total;
}

static void track(FILE* f, const char* path, const char* mode) {
  int i;
  if (!f || !underDir(path) || strpbrk(mode, "wa+") == NULL) return;
  pthread_mutex_lock(&lock);
  for (i = 0; i < MAX_TRACKED; ++i)
    if (!tracked[i]) {
      tracked[i] = f;
      break;
    }
  pthread_mutex_unlock(&lock);
}

static int isTracked(FILE* f) {
  int i;
  for (i = 0; i < MAX_TRACKED; ++i)
    if (tracked[i] == f) return 1;
  return 0;
}

/* stdio's own open (`symbol`), the file tracked when it is written under the folder. */
static FILE* openTracked(const char* symbol, const char* path, const char* mode) {
  using Open = FILE* (*)(const char*, const char*);
  FILE* f = reinterpret_cast<Open>(dlsym(RTLD_NEXT, symbol))(path, mode);
  track(f, path, mode);
  return f;
}

FILE* fopen(const char* path, const char* mode) { return openTracked("fopen", path, mode); }

FILE* fopen64(const char* path, const char* mode) { return openTracked("fopen64", path, mode); }

size_t fwrite(const void* ptr, size_t size, size_t n, FILE* f) {
  static size_t (*real)(const void*, size_t, size_t, FILE*);
  long long bytes = (long long)size * (long long)n, q = quota();
  int full = 0;
  if (!real)
    real = reinterpret_cast<size_t (*)(const void*, size_t, size_t, FILE*)>(
        dlsym(RTLD_NEXT, "fwrite"));
  if (q >= 0) {
    pthread_mutex_lock(&lock);
    if (isTracked(f)) {
      if (used < 0) used = folderBytes(faultDir());
      if (used + bytes > q) {
        full = 1;
      } else {
        used += bytes;
      }
    }
    pthread_mutex_unlock(&lock);
  }
  if (full) {
    errno = ENOSPC;
    return 0;
  }
  return real(ptr, size, n, f);
}

int fclose(FILE* f) {
  static int (*real)(FILE*);
  int i;
  if (!real) real = reinterpret_cast<int (*)(FILE*)>(dlsym(RTLD_NEXT, "fclose"));
  pthread_mutex_lock(&lock);
  for (i = 0; i < MAX_TRACKED; ++i)
    if (tracked[i] == f) tracked[i] = NULL;
  pthread_mutex_unlock(&lock);
  return real(f);
}

}  // extern "C"
