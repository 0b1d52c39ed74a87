"""Which topics of one bag are decoded while it is read (:class:`~ompn_ros.data.reader.raw.StreamPlan`).

The plan resolves the spec's topics over the bag's connections exactly as the batch reader will
(:meth:`BagContext.resolve_all` on the same topic types), with a scratch report, so the notes of
the real resolution are not doubled.  A bag the spec does not fit gives no plan: the normal read
then raises the usual error.  Cost: O(topics).
"""

from __future__ import annotations

from pathlib import Path

from ompn_ros import layout

from ..errors import BagError
from .context import BagContext
from .raw import RawBag, StreamPlan
from .report import BagReport
from .spec import ReaderSpec


def stream_plan(bag: Path, spec: ReaderSpec, types: dict[str, str]) -> StreamPlan | None:
    """The plan for ``spec`` over a bag whose topics have ``types`` (``None``: keep every topic raw).

    The observation topic, and the action topic, is decoded as read when it is a
    ``Float32MultiArray`` topic used for nothing else (its bytes are not held beside their decoded
    copy: the reader's peak memory stays about the wanted topics' bytes); with
    ``ReaderSpec.assemble`` the assembler runs while reading and only the topics another role also
    uses (action, labels, markers, ...) keep their raw bytes.
    """
    ctx = BagContext(RawBag(bag, dict(types), {}), spec, BagReport(str(bag)))
    try:
        topics = ctx.resolve_all()
    except BagError:
        return None
    others = {t for t in (topics.act, topics.sub, topics.sketch, topics.episode, topics.joints,
                          topics.split) if t}
    if topics.assemble is not None:
        return StreamPlan(assemble=topics.assemble, keep_raw=frozenset(set(topics.assemble.topics) & others))
    obs = topics.obs_type == layout.FLOAT32_ARRAY and topics.obs not in others \
        and not spec.observation.generic
    others.discard(topics.act)
    act = topics.act_type == layout.FLOAT32_ARRAY and topics.act not in others | {topics.obs} \
        and spec.action.field is None
    if not obs and not act:
        return None
    return StreamPlan(column=topics.obs if obs else None, dim=spec.observation.dim,
                      act_column=topics.act if act else None, act_dim=spec.action.dim)
