"""One client's rosbridge session, split by job:

- dispatch.py: Session. Parses each frame, checks access, dispatches it to one handler per op; levels, auth, close.
- topics.py, services.py, actions.py: the op handlers (mixed into Session, bound once into its dispatch table).
- outbox.py: what waits to be sent (replies, per-subscription queues, throttles, encodings); sans-I/O.
- fragments.py: reassembly of the fragment op.
"""

from .dispatch import Session

__all__ = ["Session"]
