# Sourced by the demo and test scripts: keep Prefect and Hugging Face state inside the work tree.
export PREFECT_HOME="${PREFECT_HOME:-$PWD/.prefect}"
export PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS="${PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS:-180}"
export PREFECT_SERVER_ANALYTICS_ENABLED=false
export PREFECT_LOGGING_LEVEL="${PREFECT_LOGGING_LEVEL:-WARNING}"
export HF_HOME="${HF_HOME:-$PWD/.prefect/hf}"
export HF_HUB_OFFLINE=1
export SVT_LOG="${SVT_LOG:-1}"
export NO_MKDOCS_2_WARNING=1
