// Atomic file writing: temporary file in the target folder, fsync, rename (owner: render).
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <set>
#include <string>
#include <system_error>
#include <thread>
#include <vector>

#include "specula/error.h"
#include "specula/image.h"

namespace specula {

namespace fs = std::filesystem;

namespace {

/// The temporary files of the writes in progress, for stop_atomic_writes(). A temporary file is
/// created and registered, and renamed and unregistered, under the mutex, so it exists exactly
/// while it is registered (as far as stop_atomic_writes can tell).
struct PendingWrites {
  std::mutex mutex;
  std::set<std::string> temp_files;
};

PendingWrites& pending() {
  static PendingWrites* p = new PendingWrites;  // never destroyed: usable until _exit
  return *p;
}

/// Test hook (tests/cli_test.cpp): SPECULA_TEST_WRITE_DELAY_MS=N sleeps N ms after the data is
/// written and before the rename, so a test can interrupt a write in that window.
void test_delay() {
  const char* env = std::getenv("SPECULA_TEST_WRITE_DELAY_MS");
  if (env == nullptr || *env == '\0') return;
  const long ms = std::strtol(env, nullptr, 10);
  if (ms > 0 && ms <= 60000) std::this_thread::sleep_for(std::chrono::milliseconds(ms));
}

}  // namespace

void stop_atomic_writes() {
  PendingWrites& p = pending();
  p.mutex.lock();  // held for good: writers now block before creating or renaming a temporary file
  for (const std::string& tmp : p.temp_files) ::unlink(tmp.c_str());
  p.temp_files.clear();
}

void check_output_path(const std::string& path) {
  if (path.empty()) throw Error("write: empty output path");
  const fs::path target(path);
  std::error_code ec;
  if (fs::is_directory(target, ec)) throw file_error(path, "is a directory");
  const fs::path dir = target.has_parent_path() ? target.parent_path() : fs::path(".");
  const fs::file_status st = fs::status(dir, ec);
  if (!fs::exists(st)) throw file_error(path, "its folder " + dir.string() + " does not exist");
  if (!fs::is_directory(st)) throw file_error(path, dir.string() + " is not a folder");
  // Creating the temporary file needs write and search permission on the folder.
  if (::access(dir.c_str(), W_OK | X_OK) != 0)
    throw file_error(path, "cannot write to its folder " + dir.string() + ": " + std::strerror(errno));
}

void write_file_atomic(const std::string& path, std::span<const uint8_t> bytes,
                       const std::string& protect) {
  check_output_path(path);  // not a folder; its folder exists and is writable
  const fs::path target(path);
  if (!protect.empty()) {
    std::error_code ec;
    if (fs::exists(target, ec) && fs::equivalent(target, fs::path(protect), ec))
      throw file_error(path, "refusing to overwrite the input file");
  }

  // The temporary file lives in the same folder so rename() is atomic (same file system).
  const fs::path dir = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::string leaf(".");
  leaf.append(target.filename().string());
  leaf.append(".tmp-XXXXXX");
  const std::string tmpl = (dir / leaf).string();
  std::vector<char> name(tmpl.begin(), tmpl.end());
  name.push_back('\0');
  PendingWrites& reg = pending();
  std::unique_lock lock(reg.mutex);
  const int fd = ::mkstemp(name.data());
  if (fd < 0) throw file_error(path, std::string("cannot create a temporary file: ") + std::strerror(errno));
  const std::string tmp(name.data());
  reg.temp_files.insert(tmp);
  lock.unlock();
  const auto forget = [&] {
    const std::lock_guard relock(reg.mutex);
    ::unlink(tmp.c_str());
    reg.temp_files.erase(tmp);
  };

  auto fail = [&](const std::string& what) {
    const int err = errno;
    ::close(fd);
    forget();
    return file_error(path, what + ": " + std::strerror(err));
  };

  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw fail("write failed");
    }
    done += static_cast<size_t>(n);
  }
  // mkstemp creates 0600: keep the mode of the file being replaced, else use rw-r--r--
  // (reading the umask would need umask(), which is process-wide and racy).
  struct stat st {};
  const mode_t mode = ::stat(path.c_str(), &st) == 0 ? (st.st_mode & 07777) : 0644;
  ::fchmod(fd, mode);
  if (::fsync(fd) != 0) throw fail("fsync failed");
  if (::close(fd) != 0) {
    const int err = errno;
    forget();
    throw file_error(path, std::string("close failed: ") + std::strerror(err));
  }
  test_delay();
  {
    const std::lock_guard relock(reg.mutex);
    if (::rename(tmp.c_str(), path.c_str()) != 0) {
      const int err = errno;
      ::unlink(tmp.c_str());
      reg.temp_files.erase(tmp);
      throw file_error(path, std::string("rename failed: ") + std::strerror(err));
    }
    reg.temp_files.erase(tmp);
  }
  // Make the rename itself durable (best effort: some file systems refuse fsync on folders).
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

}  // namespace specula
