// The farm's transport over MPI (Open MPI from Debian; compiled only when CMake finds MPI).
// Only the thread that opened it calls MPI (MPI_THREAD_FUNNELED): rank 0's worker thread
// computes pieces and never communicates.
#include <cstdlib>
#include <mpi.h>
#include <stdexcept>
#include <string>

#include "skyloop/core/error.hpp"
#include "skyloop/experiments/farm.hpp"

namespace skyloop {

namespace {
void check(int rc, const char* what) {
  if (rc != MPI_SUCCESS) throw std::runtime_error(std::string("MPI: ") + what + " failed");
}

class MpiTransport final : public Transport {
 public:
  MpiTransport() {
    int provided = 0;
    check(MPI_Init_thread(nullptr, nullptr, MPI_THREAD_FUNNELED, &provided), "MPI_Init_thread");
    if (provided < MPI_THREAD_FUNNELED) {
      MPI_Finalize();
      throw std::runtime_error("MPI: this MPI library does not support MPI_THREAD_FUNNELED");
    }
    MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
    MPI_Comm_size(MPI_COMM_WORLD, &size_);
  }
  ~MpiTransport() override { MPI_Finalize(); }
  int rank() const override { return rank_; }
  int size() const override { return size_; }
  void send(int to, int tag, const std::string& data) override {
    check(MPI_Send(data.data(), static_cast<int>(data.size()), MPI_CHAR, to, tag, MPI_COMM_WORLD), "MPI_Send");
  }
  bool try_receive(int& from, int& tag, std::string& data) override {
    int flag = 0;
    MPI_Status st;
    check(MPI_Iprobe(MPI_ANY_SOURCE, MPI_ANY_TAG, MPI_COMM_WORLD, &flag, &st), "MPI_Iprobe");
    if (!flag) return false;
    int count = 0;
    MPI_Get_count(&st, MPI_CHAR, &count);
    data.assign(static_cast<std::size_t>(count), '\0');
    check(MPI_Recv(data.data(), count, MPI_CHAR, st.MPI_SOURCE, st.MPI_TAG, MPI_COMM_WORLD, MPI_STATUS_IGNORE), "MPI_Recv");
    from = st.MPI_SOURCE;
    tag = st.MPI_TAG;
    return true;
  }
  void barrier() override { check(MPI_Barrier(MPI_COMM_WORLD), "MPI_Barrier"); }
  [[noreturn]] void abort(int code) override {
    MPI_Abort(MPI_COMM_WORLD, code);
    std::_Exit(code);
  }

 private:
  int rank_ = 0, size_ = 1;
};
}  // namespace

bool mpi_available() { return true; }

std::unique_ptr<Transport> open_transport(bool force) {
  if (!force && !launched_by_mpi()) return nullptr;
  return std::make_unique<MpiTransport>();
}

}  // namespace skyloop
