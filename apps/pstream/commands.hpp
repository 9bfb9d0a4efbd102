// The pstream subcommands; each returns the process exit code.
#pragma once

#include <cstdint>
#include <string>

namespace pstream::app {

struct InfoOptions {
  std::string file;
  bool json = false;
};
int info_alembic(const InfoOptions& options);

struct BenchReadOptions {
  std::string file;
  std::string object;  // empty: the points object with the most data
  int repetitions = 15;
  bool json = false;
};
int bench_read(const BenchReadOptions& options);

}  // namespace pstream::app
