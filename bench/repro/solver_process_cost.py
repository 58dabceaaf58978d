"""What shipping a restricted model to a solver process and a solution back would cost, per solve."""

import multiprocessing as mp
import pickle
import time

import numpy as np
import scipy.sparse as sp


def echo(conn):
    while True:
        obj = conn.recv()
        if obj is None:
            break
        conn.send(obj[1].shape)  # acknowledge


if __name__ == "__main__":
    ctx = mp.get_context("fork")
    a, b = ctx.Pipe()
    p = ctx.Process(target=echo, args=(b,))
    p.start()
    rng = np.random.default_rng(0)
    for n in (100_000, 300_000, 1_000_000, 3_764_658):
        m, per = n // 5, 6
        indptr = np.arange(0, per * n + 1, per, dtype=np.int32)
        indices = rng.integers(0, m, per * n).astype(np.int32)
        matrix = sp.csc_matrix((rng.standard_normal(per * n), indices, indptr), shape=(m, n))
        model = (rng.standard_normal(n), matrix, np.zeros(m), np.ones(m))
        t = time.perf_counter()
        blob = pickle.dumps(model, protocol=5)
        tp = time.perf_counter() - t
        t = time.perf_counter()
        a.send(model)
        a.recv()
        tr = time.perf_counter() - t
        t = time.perf_counter()
        a.send((None, np.zeros(n)))
        a.recv()
        tx = time.perf_counter() - t
        print(
            f"{n:>9} columns: pickle {len(blob) / 1e6:7.1f} MB in {tp:.3f} s; "
            f"model over a pipe {tr:.3f} s; solution back {tx:.3f} s"
        )
    a.send(None)
    p.join()
