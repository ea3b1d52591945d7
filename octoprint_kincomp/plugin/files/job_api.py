"""The HTTP side of background jobs, shared by the endpoints that start them (dry runs,
compensations, trace analyses): submitting (429 when too many wait), answering (the result
if it is ready within a few seconds, else 202 with the job to poll) and ``GET /jobs/<id>``.

A request thread only ever waits for a job, never does its work, and at most
``MAX_WAITERS`` requests wait at once (OctoPrint serves requests from a small thread pool:
the others get their 202 at once).

A job is submitted in the requesting user's name (the per-user quota and the places kept for admins,
see ``service/files/jobs.py``); ``POST /jobs/<id>/cancel`` cancels it (its owner or a KinComp admin;
409 once it has finished).
"""

from __future__ import annotations

import threading
from typing import Any, Callable, Dict, Optional

import flask
from flask_babel import gettext

from ...service.files.jobs import Job, JobQueue, QueueFull
from .. import http

WAIT_S = 2.0  # a result ready within this many seconds comes in the response itself
MAX_WAITERS = 2  # requests waiting for a result at once
RETRY_AFTER_S = 1  # the Retry-After of a 202 (twice that for a 429), in seconds


class JobApi:
    def __init__(self, jobs: JobQueue):
        self.jobs = jobs
        self._waiters = threading.BoundedSemaphore(MAX_WAITERS)

    def submit(
        self, kind: str, path: Optional[str], run: Callable, held_while_printing: bool = False
    ) -> Job:
        """``jobs.submit`` in the requesting user's name; ends the request with 429 when too
        many jobs wait (or too many of this user's)."""
        owner, admin = http.current_user()
        try:
            return self.jobs.submit(
                kind, path, run, held_while_printing=held_while_printing, owner=owner, admin=admin
            )
        except QueueFull as exc:
            resp = http.error(
                gettext("You have too many KinComp jobs waiting; wait for them or cancel one")
                if exc.mine
                else gettext("Too many KinComp jobs are waiting; try again later"),
                429,
            )
            resp.headers["Retry-After"] = str(RETRY_AFTER_S * 2)
            flask.abort(resp)

    def answer(
        self,
        job: Job,
        body: Callable[[Job], Dict[str, Any]],
        wait: float = WAIT_S,
        failed: Optional[Callable[[Job], str]] = None,
    ):
        """200 with ``body(job)`` if ``job`` is done within ``wait`` seconds, 400 with
        ``failed(job)`` (default: its error) if it failed, else 202 with the job."""
        if not job.done.is_set() and self._waiters.acquire(blocking=False):
            try:
                job.done.wait(wait)
            finally:
                self._waiters.release()
        if job.state == "done":
            return flask.jsonify(body(job))
        if job.state == "failed":
            if job.exception is not None and http.disk_full(job.exception):
                return http.os_error(job.exception)  # 507: nothing was kept
            if failed is not None:
                return http.error(failed(job), 400)
            return http.error(
                http.tr(job.exception) if job.exception is not None else str(job.error), 400
            )
        resp = flask.make_response(flask.jsonify(job=job.to_dict()), 202)
        resp.headers["Retry-After"] = str(RETRY_AFTER_S)  # when to ask GET /jobs/<id>
        return resp

    @http.route("/jobs/<job_id>", "GET", needs=(http.STATUS,))
    def job(self, job_id: str):
        """GET /jobs/<id>: one job (state, progress, result or error)."""
        job = self.jobs.get(job_id)
        if job is None:
            return http.error(gettext("No such job"), 404)
        return flask.jsonify(job=job.to_dict())

    @http.route("/jobs/<job_id>/cancel", "POST", needs=(http.STATUS,))
    def cancel(self, job_id: str):
        """POST /jobs/<id>/cancel: cancels the job (its owner or a KinComp admin)."""
        job = self.jobs.get(job_id)
        if job is None:
            return http.error(gettext("No such job"), 404)
        user, admin = http.current_user()
        if not admin and (user is None or job.owner != user):
            return http.error(
                gettext("Only the user who started a job or a KinComp admin can cancel it"), 403
            )
        if not self.jobs.cancel(job):
            if job.cancelled and job.active:  # a second cancel of a job still ending
                return http.error(gettext("The job is being cancelled already"), 409)
            return http.error(gettext("The job has already finished"), 409)
        return flask.jsonify(job=job.to_dict())
