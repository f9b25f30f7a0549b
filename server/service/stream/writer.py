"""The writer half of a stream connection (connection.py): takes the owed answers in order,
waits for each one's outcome (image, error or dropped) and sends it; after the last, GOODBYE
when the connection ends in an orderly way. Whatever ends it, what is still owed is cancelled.
"""

from __future__ import annotations

import logging
import socket

from sphrender.core.protocol import MessageType, encode_message
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.render.jobs import ErrorOutcome, Outcome
from sphrender.server.service.stream.answers import Answers, Slot, answer_bytes
from sphrender.server.service.stream.handshake import LINGER_S
from sphrender.server.service.stream.wire import TICK_S, Channel, Closed

log = logging.getLogger("sphrender.service.stream")


def send_counted(channel: Channel, service: ServiceFacade, data: bytes) -> None:
    """Send `data` and count its bytes (``sphrender_bytes_out_total{transport="stream"}``)."""
    channel.send_all(data)
    service.metrics.transport.bytes_out.inc("stream", amount=len(data))


def _error_of(outcome: Outcome) -> tuple[str, str]:
    """A fatal answer's code and text (what a WebSocket Close frame repeats)."""
    if isinstance(outcome, ErrorOutcome):
        return outcome.code, outcome.message
    return "protocol", "the connection is closed"


class AnswerWriter:
    """See the module docstring; `run` on a thread of its own."""

    def __init__(
        self,
        sock: socket.socket,
        channel: Channel,
        service: ServiceFacade,
        answers: Answers,
        session_id: str,
        peer: str,
    ) -> None:
        self.sock = sock
        self.channel = channel
        self.service = service
        self.answers = answers
        self.session_id = session_id
        self.peer = peer

    def _outcome(self, slot: Slot) -> Outcome | None:
        if slot.outcome is not None:
            return slot.outcome
        assert slot.job is not None
        while not self.answers.dead.is_set():
            try:
                return slot.job.future.result(timeout=TICK_S)
            except TimeoutError:
                continue
        return None

    def run(self) -> None:
        """Send the answers in order, then GOODBYE; on the way out, cancel what is left."""
        try:
            while True:
                slot = self.answers.first()
                if slot is None:
                    break
                outcome = self._outcome(slot)
                if outcome is None:
                    raise Closed("gone")
                send_counted(self.channel, self.service, answer_bytes(slot, outcome))
                if slot.release is not None:
                    slot.release()
                self.answers.sent_first()
                if slot.fatal:
                    self.channel.close_for_error(*_error_of(outcome))
                    return
            if self.answers.goodbye is not None:
                send_counted(
                    self.channel,
                    self.service,
                    encode_message(MessageType.GOODBYE, {"reason": self.answers.goodbye}),
                )
                self.channel.end_orderly(self.answers.goodbye, LINGER_S)
        except Closed as closed:
            log.info(
                "stream client gone while answering",
                extra={"event": "stream_write_failed", "peer": self.peer, "reason": closed.reason},
            )
            self.answers.dead.set()
        finally:
            self._abandon()
            self.channel.shutdown()

    def _abandon(self) -> None:
        """Cancel whatever is still owed (the client cannot receive it any more)."""
        for slot in self.answers.abandon():
            if slot.job is not None:
                slot.job.cancel()
            if slot.release is not None:
                slot.release()
        self.service.scheduler.cancel_key(self.session_id)
