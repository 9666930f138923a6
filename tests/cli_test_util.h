// Running the specula command-line tool from tests: exit code, stdout and stderr.
#pragma once

#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace specula::test {

struct RunResult {
  int exit_code = -1;
  bool signaled = false;
  std::string out, err;
};

inline std::string slurp(const std::filesystem::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

/// Runs the CLI (SPECULA_CLI_PATH) with \p args, shell-quoted by the caller, in the folder
/// \p dir (where stdout.txt / stderr.txt are captured).
inline RunResult run_cli(const std::string& args, const std::filesystem::path& dir) {
  const std::filesystem::path out = dir / "stdout.txt", err = dir / "stderr.txt";
  const std::string cmd = std::string("'") + SPECULA_CLI_PATH + "' " + args + " >'" + out.string() + "' 2>'" +
                          err.string() + "' </dev/null";
  const int status = std::system(cmd.c_str());
  RunResult r;
  if (WIFEXITED(status)) r.exit_code = WEXITSTATUS(status);
  // std::system runs /bin/sh, which reports a child killed by signal N as exit 128+N.
  r.signaled = WIFSIGNALED(status) || (r.exit_code > 128);
  r.out = slurp(out);
  r.err = slurp(err);
  return r;
}

}  // namespace specula::test
