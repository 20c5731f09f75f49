# the pages' browser libraries, pinned by package-lock.json
FROM node:20-slim AS pages
WORKDIR /build
COPY package.json package-lock.json ./
RUN npm ci --no-audit --no-fund

FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 NUMBA_CACHE_DIR=/tmp/numba \
    VANTAGE_DATA_DIR=/data
WORKDIR /srv/vantage

COPY pyproject.toml README.md ./
COPY app ./app
RUN pip install --no-cache-dir '.[s3]'

COPY --from=pages /build/node_modules ./node_modules
COPY alembic.ini ./
COPY migrations ./migrations

VOLUME /data
EXPOSE 8000
# migrations first, then the service (several processes may share /data and one PostgreSQL)
# (app.serve: uvicorn, with the workers' Prometheus counters summed by every /metrics scrape)

CMD ["sh", "-c", "alembic upgrade head && exec python -m app.serve --host 0.0.0.0 --port 8000 --workers ${VANTAGE_WORKERS:-2} --forwarded-allow-ips \"${VANTAGE_FORWARDED_ALLOW_IPS:-*}\""]
