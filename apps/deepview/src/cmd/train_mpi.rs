//! `mpirun -np N deepview train ...` (feature `openmpi`): one training replica per MPI rank, through the
//! `mpi` crate (Open MPI, MPICH, ...). The training side is `deepview_train::dist`.
//!
//! An error or a panic on any rank prints `error: rank R of N: <reason>` and calls `MPI_Abort`, which
//! stops every rank of the job (instead of leaving the others waiting in a collective call).

use anyhow::Context;
use deepview_train::Collective;
use mpi::collective::SystemOperation;
use mpi::environment::Threading;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use std::io::Write;
use std::rc::Rc;

/// `MPI_COMM_WORLD` as the trainer's communicator.
struct Mpi {
    world: SimpleCommunicator,
    rank: usize,
    size: usize,
}

impl Collective for Mpi {
    fn rank(&self) -> usize {
        self.rank
    }

    fn size(&self) -> usize {
        self.size
    }

    fn all_reduce_sum(&self, buf: &mut [f32]) {
        let send = buf.to_vec();
        self.world
            .all_reduce_into(&send[..], buf, SystemOperation::sum());
    }

    fn broadcast_f32(&self, buf: &mut [f32]) {
        self.world.process_at_rank(0).broadcast_into(buf);
    }

    fn broadcast_u64(&self, buf: &mut [u64]) {
        self.world.process_at_rank(0).broadcast_into(buf);
    }
}

/// Initialise MPI, run `train` as this rank, finalise; on an error or panic on this rank, print it
/// with the rank and abort the whole job.
pub fn run_ranks(
    train: impl FnOnce(Rc<dyn Collective>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    // Replicas of one rank run in threads (`--devices cpu,cpu`); only the main thread calls MPI.
    let (universe, _) = mpi::initialize_with_threading(Threading::Funneled)
        .context("cannot initialise MPI (was this process started by mpirun?)")?;
    let world = universe.world();
    let (rank, size) = (world.rank() as usize, world.size() as usize);
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        eprint!("rank {rank} of {size}: ");
        default_hook(info);
    }));
    let comm = Rc::new(Mpi { world, rank, size });
    let dyn_comm: Rc<dyn Collective> = comm.clone();
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| train(dyn_comm)));
    let code = match result {
        Ok(Ok(())) => return Ok(()), // `universe` drops here: MPI_Finalize on every rank
        Ok(Err(e)) => (
            2,
            format!("error: rank {rank} of {size}: {e:#}; stopping all ranks\n"),
        ),
        Err(_) => (
            101,
            format!("error: rank {rank} of {size} panicked (see above); stopping all ranks\n"),
        ),
    };
    let (code, message) = code;
    // One write, so that the lines of several ranks do not interleave.
    let mut err = std::io::stderr().lock();
    let _ = err.write_all(message.as_bytes());
    let _ = err.flush();
    drop(err);
    comm.world.abort(code)
}
