"""The "neumat" plugin factory builds one BSDF at a time: Mitsuba instantiates a scene's plugins on several threads,
and the factory's first imports from two threads at once once left a CI run with the Dr.Jit runtime package partly
initialised ("unknown program 'healpix-grid-mlp'"). No Mitsuba needed: the factory's collaborators are stand-ins."""
from __future__ import annotations

import threading
import time
from types import SimpleNamespace

from neumat.integrations import mitsuba_native


def test_the_factory_builds_one_bsdf_at_a_time(monkeypatch):
    inside, most, lock = [0], [0], threading.Lock()

    def slow_runtime(source, backend, compute=None, mlp_form=None):  # stands in for the imports and the translation
        with lock:
            inside[0] += 1
            most[0] = max(most[0], inside[0])
        time.sleep(0.05)
        with lock:
            inside[0] -= 1
        return None

    monkeypatch.setattr(mitsuba_native, "native_runtime", slow_runtime)
    monkeypatch.setattr(mitsuba_native, "_BRIDGE", lambda mi: (lambda props: ("bridge", props["filename"])))
    mi = SimpleNamespace(Float=float)
    built = []
    threads = [threading.Thread(target=lambda k=k: built.append(mitsuba_native.make_bsdf(mi,
                                                                                         {"filename": f"m{k}.nmat"})))
               for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(built) == [("bridge", f"m{k}.nmat") for k in range(4)]
    assert most[0] == 1
